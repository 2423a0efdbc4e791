"""A pelvis phantom's file, its fit to the model and the headset placement the display calibration gives."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thrsim.app import controls as c
from thrsim.app.navigation import CALIBRATION_SAMPLES, NavigationTrainer
from thrsim.errors import ThrsimInputError
from thrsim.nav.phantom import FIT_LANDMARKS, SIMULATED_PHANTOM, headset_from_model, phantom_from_file, read_phantom_file
from thrsim.nav.rigid import invert, make_pose, transform_points
from thrsim.session.file import read_session


def _pose(seed: int, reach_m: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_pose(Rotation.random(random_state=seed), rng.uniform(-reach_m, reach_m, 3))


def test_the_shipped_phantom_is_the_simulated_pelvis_with_its_array_on_the_right_crest():
    phantom = phantom_from_file(read_phantom_file(SIMULATED_PHANTOM))
    simulated = NavigationTrainer("right")
    assert np.allclose(phantom.reference_from_model, simulated.model_to_reference, atol=1e-6)
    assert phantom.fit.rms < 1e-6 and len(phantom.fit.residuals) == len(FIT_LANDMARKS)


def test_a_printed_phantom_in_another_frame_is_fitted_to_that_frame(tmp_path):
    """A lab's print with its array elsewhere: the landmarks (probed to 0.5 mm) give its frame to well under a millimetre."""
    reference_from_model = _pose(3, 0.3)
    rng = np.random.default_rng(4)
    simulated = NavigationTrainer("right")
    landmarks = {n: transform_points(reference_from_model, simulated.model_landmarks[n][None])[0] * 1e3 for n in FIT_LANDMARKS}
    probed = {n: (p + rng.normal(0, 0.5, 3)).tolist() for n, p in landmarks.items()}
    path = tmp_path / "print.json"
    path.write_text(json.dumps({"name": "lab print", "landmarks_mm": probed, "calibration_target_mm": [0, 0, 0]}))
    phantom = phantom_from_file(read_phantom_file(path))
    assert np.linalg.norm(phantom.reference_from_model[:3, 3] - reference_from_model[:3, 3]) < 1e-3
    trainer = NavigationTrainer("left", phantom=phantom)  # one phantom serves either hip
    assert np.allclose(trainer.model_to_reference, phantom.reference_from_model)


@pytest.mark.parametrize(
    ("content", "says"),
    [
        ("{not json", "phantom"),
        (
            '{"name": "x", "landmarks_mm": {"a": [0, 0, 0], "b": [1, 0, 0], "c": [0, 1, 0]}, "calibration_target_mm": [0, 0, 0], "colour": 1}',
            "colour",
        ),
        (
            '{"name": "x", "landmarks_mm": {"a": [0, 0, 0], "b": [1, 0, 0], "c": [0, 1, 0]}, "calibration_target_mm": [0, 0, 0]}',
            "at least 3",
        ),
        (
            '{"name": "x", "landmarks_mm": {"asis_right": [0, 0], "b": [1, 0, 0], "c": [0, 1, 0]}, "calibration_target_mm": [0, 0, 0]}',
            "landmarks_mm",
        ),
    ],
)
def test_a_bad_phantom_file_is_refused_in_one_line(tmp_path, content, says):
    path = tmp_path / "phantom.json"
    path.write_text(content)
    with pytest.raises(ThrsimInputError, match=says) as refused:
        read_phantom_file(path)
    assert "\n" not in str(refused.value)


def test_a_phantom_that_is_not_this_pelvis_is_refused(tmp_path):
    definition = json.loads(SIMULATED_PHANTOM.read_text())
    definition["landmarks_mm"]["asis_left"] = [x + 40.0 for x in definition["landmarks_mm"]["asis_left"]]
    path = tmp_path / "other.json"
    path.write_text(json.dumps(definition))
    with pytest.raises(ThrsimInputError, match="not this pelvis"):
        read_phantom_file(path)


def test_headset_placement_composes_calibration_tracker_and_phantom():
    head_from_tracker, tracker_from_reference, reference_from_model = _pose(1), _pose(2), _pose(3, 0.3)
    placed = headset_from_model(head_from_tracker, tracker_from_reference, reference_from_model)
    point = np.array([0.01, 0.02, -0.03])
    expected = transform_points(
        head_from_tracker, transform_points(tracker_from_reference, transform_points(reference_from_model, point[None]))
    )
    assert np.allclose(transform_points(placed, point[None]), expected)


def _calibrate(trainer: NavigationTrainer, head_from_tracker: np.ndarray, noise_m: float = 0.0, seed: int = 0) -> dict:
    """The controller held on the target for a second: its pose as a headset reports it."""
    rng = np.random.default_rng(seed)
    trainer.apply_control(c.parse_control({"type": "headset", "action": "start"}), 0.0)
    target = head_from_tracker @ invert(trainer.camera_pose) @ trainer._headset_target()
    for i in range(CALIBRATION_SAMPLES):
        held = target.copy()
        held[:3, 3] += rng.normal(0, noise_m, 3)
        trainer.apply_control(c.parse_control({"type": "headset", "action": "target", "pose": held.ravel().tolist()}), 0.01 * i)
    return trainer.step(1.0)["headset"]


def test_the_headset_calibration_places_the_bone_where_the_tracker_sees_the_phantom():
    trainer = NavigationTrainer("right")
    head_from_tracker = _pose(5, 2.0)
    headset = _calibrate(trainer, head_from_tracker, noise_m=0.5e-3)
    assert headset["state"] == "done" and headset["result"]["translation_residual_rms_mm"] < 2.0
    expected = head_from_tracker @ invert(trainer.camera_pose) @ trainer.scene_to_reference
    placement = np.array(headset["placement"]).reshape(4, 4)
    assert np.linalg.norm(placement[:3, 3] - expected[:3, 3]) < 0.5e-3
    # the tracker now sees the reference array (the phantom) moved: the bone follows it
    moved = _pose(6, 1.0)
    trainer.apply_pose("ReferenceToTracker", moved, 1.1)
    placement = np.array(trainer.step(1.2)["headset"]["placement"]).reshape(4, 4)
    assert np.allclose(placement, head_from_tracker @ moved @ trainer.scene_to_reference, atol=1e-3)


def test_a_headset_calibration_with_the_controller_moving_is_refused():
    trainer = NavigationTrainer("right")
    headset = _calibrate(trainer, _pose(5, 2.0), noise_m=0.05)
    assert headset["state"] == "refused" and headset["placement"] is None and "inconsistent" in headset["message"]


def test_a_controller_aims_the_reamer_along_its_shaft():
    trainer = NavigationTrainer("right")
    from thrsim.nav.anatomy import local_axis_from_angles

    shaft = trainer.true_app_model.to_world(local_axis_from_angles(35.0, 20.0))
    trainer.apply_control(c.parse_control({"type": "reamer_axis", "axis": (3 * shaft).tolist()}), 0.0)
    assert trainer._reamer_angles == pytest.approx({"inclination_deg": 35.0, "anteversion_deg": 20.0})
    trainer.apply_control(c.parse_control({"type": "reamer_axis", "axis": (-shaft).tolist()}), 0.1)  # into the pelvis: stops at the limits
    assert 0.0 <= trainer._reamer_angles["inclination_deg"] <= 90.0
    with pytest.raises(ThrsimInputError, match="direction"):
        c.parse_control({"type": "reamer_axis", "axis": [0, 0, 0]})


def test_serve_refuses_a_bad_phantom_file_in_one_line(tmp_path, monkeypatch, capsys):
    from checkout_cli import run_main

    bad = tmp_path / "phantom.json"
    bad.write_text('{"name": "x", "landmarks_mm": {}, "calibration_target_mm": [0, 0, 0]}')
    sessions = tmp_path / "sessions"
    code, out, err = run_main(monkeypatch, capsys, "serve", "--phantom", str(bad), "--sessions", str(sessions), "--port", "0")
    assert code == 2 and "landmarks_mm" in err and len(err.strip().splitlines()) == 1 and out == "" and not sessions.exists()


def test_sessions_record_the_phantom_and_rebuild_it():
    """The served phantom is in every mode's session settings (JSON), so a replay's trainer stands on it too."""
    from thrsim.app.modes import MODES
    from thrsim.app.server import ServeSettings

    definition = read_phantom_file(SIMULATED_PHANTOM)
    settings = MODES["navigation"].session_settings(ServeSettings(phantom=definition))
    assert json.loads(json.dumps(settings)) == settings and settings["phantom"]["name"] == definition.name
    trainer = MODES["navigation"].make_trainer({"side": "left", **settings})
    assert trainer.phantom is not None and np.allclose(trainer.model_to_reference, phantom_from_file(definition).reference_from_model)
    assert trainer.scene()["phantom"]["landmarks"] == len(FIT_LANDMARKS)


def test_a_headset_session_on_a_phantom_replays_alike(tmp_path):
    """The phantom in the settings, the headset's calibration and a controller's aim in the journal: the replay re-lives them."""
    from thrsim.app.live import LiveSession
    from thrsim.app.modes import MODES
    from thrsim.app.replay import replay_session
    from thrsim.app.server import ServeSettings

    settings = {
        "side": "right",
        "seed": 1,
        **MODES["navigation"].session_settings(ServeSettings(phantom=read_phantom_file(SIMULATED_PHANTOM))),
    }
    now = [0.0]
    session = LiveSession(MODES["navigation"], settings, lambda: now[0], tmp_path)
    trainer = session.trainer
    target = _pose(5, 2.0) @ invert(trainer.camera_pose) @ trainer._headset_target()
    session.control({"type": "headset", "action": "start"})
    for i in range(CALIBRATION_SAMPLES):
        now[0] = 0.01 * i
        session.control({"type": "headset", "action": "target", "pose": target.ravel().tolist()})
    now[0] = 1.0
    assert session.tick()["headset"]["state"] == "done"
    session.control({"type": "reamer_axis", "axis": [0.5, 0.2, -0.6]})
    now[0] = 1.5
    session.tick()
    path = session.save()
    assert read_session(path).settings["phantom"] == settings["phantom"]  # what a replay's trainer is built from
    outcome = replay_session(path)
    assert outcome.refused_controls == 0 and outcome.events_match and outcome.trace_match and outcome.events > 0
