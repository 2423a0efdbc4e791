"""The report of a whole-socket session: a scripted session of the shipped socket model (the native
46 mm socket meshed coarse, a 48 mm cup planned, the 46 mm reamer then the 48 mm one at the safe
zone's centre) saved to its HDF5 file, and every figure of its report checked against what the test
computes itself from the socket's own mesh and the trainer's trace: the sequence and the time with
each reamer, the removed volume, the cavity's floor, over- and under-reaming, the medial wall left,
the centre, the push and the path, the depth map's orientation, and the events."""

from __future__ import annotations

import html

import numpy as np
import pytest
from app_helpers import SocketSession

from thrsim.app.reaming import socket_in_patch
from thrsim.config import SafeZone
from thrsim.nav.bone_frame import patch_in_app
from thrsim.report import build_report
from thrsim.report.reaming import CLASSES, cavity_map, map_axes
from thrsim.report.reaming_metrics import metrics
from thrsim.session.file import read_session
from thrsim.session.reaming import read_reaming

pytestmark = pytest.mark.timeout(900)

STEP = 1 / 60
#: a coarse socket: the report's arithmetic, not the mesh's resolution, is under test (fine enough
#: that the reamers reach neither the medial wall nor the modelled bone's cut edge)
ELEMENT_MM = 3.0
#: the reamers and the simulated seconds each reams
SEQUENCE = ((46, 0.5), (48, 0.75))


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """The scripted session, its trainer's final state and the saved file."""
    folder = tmp_path_factory.mktemp("socket-report")
    scripted = SocketSession(folder, ELEMENT_MM, STEP)
    send, live = scripted.send, scripted.live
    send(type="plan", cup_diameter_mm=48, medialisation_mm=0, superior_shift_mm=0, inclination_deg=40, anteversion_deg=15)
    states = []
    for size, seconds in SEQUENCE:
        send(type="reamer_size", size_mm=size)
        send(type="run", action="start")
        for _ in range(int(round(seconds / STEP))):
            states.append(scripted.tick())
        send(type="run", action="pause")
    send(type="confirm_cup")
    trainer = live.trainer
    sim = trainer.simulator
    final = {"alpha": sim.alpha.copy(), "threshold": sim.model.threshold, "volumes": sim.model.graph.volumes.copy(), "states": states}
    path = live.save(folder)
    return trainer, final, path


def test_the_socket_session_reams_the_cases_socket_with_the_trainees_reamers(session):
    trainer, final, path = session
    record = read_reaming(read_session(path).groups["reaming"])
    assert trainer.simulator.socket and record.cut_mm is not None and np.array_equal(record.cut_mm, record.reamer_mm)
    assert record.removed_volume_mm3[-1] > 100.0  # the 48 mm reamer cut the socket's rim and dome
    assert record.medial_wall_mm is not None  # the socket has a medial wall


def test_the_report_of_a_socket_session_matches_the_socket_mesh_and_the_trace(session):
    trainer, final, path = session
    record = read_reaming(read_session(path).groups["reaming"])
    found = metrics(record)
    mesh = socket_in_patch(46.0, ELEMENT_MM)  # the same socket meshed again, independently of the trainer
    assert mesh.n_tets == len(final["alpha"])
    removed = final["alpha"] < final["threshold"]
    # the reamer sequence and the time with each: the trace's frames per size
    sizes = [size for size, _ in SEQUENCE]
    assert found["reamer_sequence_mm"] == sizes
    frames = [int(np.sum(record.reamer_mm == size)) for size in sizes]
    assert found["time_per_reamer_s"] == pytest.approx([n * record.frame_dt_s for n in frames])
    assert frames == [round(seconds / STEP) for _, seconds in SEQUENCE]  # the model's frame is the page's 1/60 s
    assert found["cavity_diameter_mm"] == 48.0 and found["cavity_diameter_error_mm"] == 0.0
    # the removed volume: the removed elements' volumes
    volume_mm3 = float(final["volumes"][removed].sum()) * 1e9
    assert record.removed_volume_mm3[-1] == pytest.approx(volume_mm3, rel=1e-6)
    # the plan at the zone's centre: its axis the patch frame's +z, its centre the native centre
    centroids = mesh.centroids * 1e3
    distance = np.linalg.norm(centroids, axis=1)
    native_mm = float(np.median(np.linalg.norm(mesh.nodes[mesh.node_sets["articular"]], axis=1))) * 1e3
    assert native_mm == pytest.approx(23.0, abs=0.01)
    floor_mm = max(float(np.max(-centroids[removed, 2])), native_mm)  # the native hollow counts: nothing is reamed there yet
    inside = ~removed & (distance < 24.0) & (centroids[:, 2] < 0.0)
    assert found["cavity_depth_error_mm"] == pytest.approx(floor_mm - 24.0, abs=1e-4)
    assert found["over_reaming_mm"] == pytest.approx(max(0.0, float(np.max(distance[removed])) - 24.0), abs=1e-4)
    assert found["under_reaming_mm"] == pytest.approx(float(np.max(24.0 - distance[inside])), abs=1e-4)
    # the medial wall left: the least distance from the reamer's teeth to the nodes of the elements touching the
    # mesh's medial wall (all their nodes: an element goes when the teeth reach one) over the frames; none went
    wall_elements = np.isin(mesh.tets, mesh.node_sets["medial_wall"]).any(axis=1)
    assert not removed[wall_elements].any()
    wall = mesh.nodes[np.unique(mesh.tets[wall_elements])]
    teeth = np.array([np.min(np.linalg.norm(wall - p, axis=1)) for p in record.position_m]) - record.cut_mm * 0.5e-3
    assert found["medial_wall_remaining_mm"] == pytest.approx(max(0.0, float(teeth.min())) * 1e3, abs=1e-6)
    assert final["states"][-1]["bone_left_mm"] == pytest.approx(max(0.0, teeth[-1]) * 1e3, abs=1e-6)
    # the centre: the 48 mm reamer's centre at its deepest, in the hip's medial and superior directions
    deepest = np.flatnonzero(record.reamer_mm == 48.0)[np.argmax(record.depth_mm[record.reamer_mm == 48.0])]
    lateral, _, inferior = patch_in_app(SafeZone()) @ record.position_m[deepest]
    assert (found["medialisation_mm"], found["superior_shift_mm"]) == pytest.approx((-lateral * 1e3, -inferior * 1e3))
    # aimed at the plan throughout: the cavity's axis and the confirmed cup on it
    assert found["inclination_error_deg"] == pytest.approx(0.0, abs=1e-6) and found["anteversion_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert found["confirmed_inclination_error_deg"] == pytest.approx(0.0, abs=1e-6) and found["within_5deg_fraction"] == 1.0
    # the push: the default 230 N throughout; a socket model reads the feed the push balances, not the push: no learned push to score
    assert found["push_mean_n"] == 230.0 and record.trained_force_n is None and "push_out_of_range_fraction" not in found
    steps = np.linalg.norm(np.diff(record.position_m, axis=0), axis=1)[np.diff(record.frame) == 1]
    assert found["reamer_path_length_mm"] == pytest.approx(float(steps.sum()) * 1e3)
    kinds = [e["kind"] for e in record.events]
    assert kinds.count("reamer_changed") == 2  # 44 → 46 → 48 (a 48 mm cup starts at 44 mm)
    outside = [e for e in record.events if e["kind"].endswith("_out_of_range")]

    page = build_report(path)
    assert "46 → 48 mm" in page and "planned 48 mm cup" in page
    for event in outside:  # the error catalogue lists every input outside what the model learned
        assert f"<td>{event['kind'].replace('_', ' ')}</td><td>{html.escape(event['detail'])}</td>" in page
    assert f"<td>{volume_mm3:.1f} mm³</td>" in page
    for name in ("cavity_depth_error_mm", "over_reaming_mm", "under_reaming_mm", "medial_wall_remaining_mm"):
        assert f"<td>{found[name]:.1f} mm</td>" in page, name
    assert "patch" not in page.replace("bone patch has no medial wall", "")  # nothing said of a bone this session did not ream


def test_the_depth_map_of_the_socket_is_drawn_against_the_planned_cup(session):
    _, final, path = session
    record = read_reaming(read_session(path).groups["reaming"])
    found = cavity_map(record)
    assert found["against_cup"] and found["planned_radius_mm"] == 24.0
    element_mm = record.cavity["element_size_m"] * 1e3
    assert 0.7 * ELEMENT_MM < element_mm < 1.6 * ELEMENT_MM  # the socket's own elements, not the patch's 0.45 mm
    assert found["tolerance_mm"] == pytest.approx(element_mm / 2)
    counted = [name for name in CLASSES if name != "native hollow"]
    assert sum(found["fractions"][name] for name in counted) == pytest.approx(1.0)
    assert found["fractions"]["on plan"] + found["fractions"]["over-reamed"] > 0.0  # the 48 mm reamer cut to the plan somewhere
    anterior, superior = map_axes(np.array([0.0, 0.0, 1.0]))
    assert anterior == pytest.approx([0.0, 1.0, 0.0]) and superior == pytest.approx([-1.0, 0.0, 0.0])  # the patch frame's +x is inferior
    # the cells a removed element lies in (below the rim): never "not reached"
    reamed = _reamed_cells(found, record, final["alpha"] < final["threshold"])
    assert not np.any(found["classes"][reamed] == CLASSES.index("not reached"))


def _reamed_cells(found: dict, record, removed: np.ndarray) -> np.ndarray:
    """The map's cells (seen along the patch frame's +z) that a removed element below the rim lies in."""
    anterior, superior = map_axes(np.array([0.0, 0.0, 1.0]))
    cells = found["classes"].shape[0]
    grid = (found["extent_mm"][1] - found["extent_mm"][0]) / cells
    centre = record.cavity["centroids_m"][removed] * 1e3
    index = np.floor((np.column_stack([centre @ anterior, centre @ superior]) - found["extent_mm"][0]) / grid).astype(int)
    inside = ((index >= 0) & (index < cells)).all(axis=1) & (centre[:, 2] < 0.0)
    reamed = np.zeros_like(found["classes"], dtype=bool)
    reamed[index[inside, 0], index[inside, 1]] = True
    return reamed


def test_the_depth_map_has_superior_up(tmp_path):
    """The native surface lies deepest at the fossa, 25° from the pole toward inferior: after the 46 mm
    reamer alone (line to line, it leaves the fossa), the deepest native cells lie below the map's middle."""
    scripted = SocketSession(tmp_path, ELEMENT_MM, STEP)
    scripted.send(type="plan", cup_diameter_mm=48, medialisation_mm=0, superior_shift_mm=0, inclination_deg=40, anteversion_deg=15)
    scripted.send(type="reamer_size", size_mm=46)
    scripted.send(type="run", action="start")
    for _ in range(30):
        scripted.tick()
    scripted.send(type="run", action="pause")
    sim = scripted.live.trainer.simulator
    removed = sim.alpha < sim.model.threshold
    record = read_reaming(read_session(scripted.live.save(tmp_path)).groups["reaming"])
    found = cavity_map(record)
    classes, error = found["classes"], found["error_mm"]
    cells = classes.shape[0]
    middle = (np.arange(cells) - cells / 2 + 0.5) * (found["extent_mm"][1] - found["extent_mm"][0]) / cells
    native = ~_reamed_cells(found, record, removed) & (classes >= 0)
    beyond = np.where(classes == CLASSES.index("native hollow"), np.inf, error)  # a hollow (no surface to measure) is deepest of all
    deepest = np.argwhere(native & (beyond >= np.nanpercentile(np.where(native, beyond, np.nan), 90)))
    assert len(deepest) and float(np.mean(middle[deepest[:, 1]])) < -2.0


def test_the_reamer_reaching_cancellous_bone_is_an_event_once_a_reamer(tmp_path):
    """Reamed one size up the 48 mm reamer seats in the plate; the 50 mm one after it reaches the
    cancellous bone: one event for each reamer that did, however often the layer changes under it."""
    scripted = SocketSession(tmp_path, ELEMENT_MM, STEP)
    layers: dict[int, list] = {}
    for size, seconds in ((48, 0.5), (50, 0.25)):
        scripted.send(type="reamer_size", size_mm=size)
        scripted.send(type="run", action="start")
        layers[size] = [scripted.tick()["cutting_layer"] for _ in range(int(round(seconds / STEP)))]
        scripted.send(type="run", action="pause")
    said = [
        e["detail"]
        for e in read_reaming(read_session(scripted.live.save(tmp_path)).groups["reaming"]).events
        if e["kind"] == "cancellous_reached"
    ]
    reached = [size for size in layers if "cancellous" in layers[size]]
    assert 50 in reached and said == [f"the {size} mm reamer left the subchondral plate for cancellous bone" for size in reached]


def test_a_socket_perforated_and_undone_still_counts_and_scores(tmp_path):
    """Pushed at the most a hand pushes, the 48 mm reamer goes through the coarse socket's bone; undone,
    the bone is whole again, the record is not: the criterion says when, and scores nothing."""
    from thrsim.report.reaming import criteria

    scripted = SocketSession(tmp_path, ELEMENT_MM, STEP)
    live = scripted.live
    scripted.send(type="reamer_size", size_mm=48)
    scripted.send(type="force", newton=400)
    scripted.send(type="run", action="start")
    while live.trainer.running and scripted.now < 5.0:
        scripted.tick()
    breach = [e for e in live.trainer.events if e["kind"] in ("perforated", "medial_wall_breached")]
    assert len(breach) == 1, [e["kind"] for e in live.trainer.events]
    scripted.send(type="run", action="undo")
    record = read_reaming(read_session(live.save(tmp_path)).groups["reaming"])
    assert cavity_map(record)["fractions"]["perforated"] == 0.0  # the final bone, undone, is whole
    first = criteria(record)[0]
    assert first.name == "no perforation or breach" and first.points == 0.0
    assert first.measured.endswith(f"at {breach[0]['time_s']:.1f} s, then undone")
