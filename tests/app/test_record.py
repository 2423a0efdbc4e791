"""The trainees' record from sessions lived through the real trainer and saved as real HDF5 files:
the trainee in the file, registration by placing the probe (careful and careless placements
measured and scored apart), the summaries, CSV and JSON exports (library and ``thrsim sessions
export``), and the post-session questionnaire."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest
from checkout_cli import run_main

from thrsim.app.live import LiveSession
from thrsim.app.modes import MODES
from thrsim.app.replay import replay_session
from thrsim.errors import ThrsimInputError
from thrsim.report import build_assessment
from thrsim.report.record import of_trainee, session_files, summaries, to_csv, to_json
from thrsim.session import read_session
from thrsim.session.questionnaire import ITEMS, read_questionnaire, write_questionnaire

LANDMARKS = 4


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def placed_session(folder: Path, trainee: str, miss_mm: float) -> Path:
    """A trainee places the probe on the first landmarks, ``miss_mm`` beside each (in the view's plane), and holds it still."""
    clock = FakeClock()
    session = LiveSession(MODES["navigation"], {"side": "right", "seed": 3}, clock, folder)

    def run(seconds: float) -> None:
        for _ in range(int(seconds * 60)):
            clock.now += 1 / 60
            session.tick()

    session.control({"type": "trainee", "id": trainee})
    run(0.1)
    for _ in range(LANDMARKS):
        target = session.trainer.registration.current_target
        tip_mm = session.trainer.model_landmarks[target] * 1e3 + np.array([miss_mm, 0.0, 0.0])
        session.control({"type": "probe", "action": "place", "tip_mm": tip_mm.tolist()})
        run(0.8)
        assert session.trainer.registration.current_target != target, "the placed probe acquired its landmark"
    return session.save()


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("sessions")
    placed_session(folder, "Trainee 7", miss_mm=0.3)
    placed_session(folder, "trainee 7 ", miss_mm=4.2)
    placed_session(folder, "Other", miss_mm=1.0)
    return folder


def _by_error(rows: list[dict]) -> list[dict]:
    return sorted(rows, key=lambda r: r["metrics"]["acquisition_error_mean_mm"])


def test_the_file_names_its_trainee_and_a_replay_lives_the_same_session(folder):
    names = {path: read_session(path).attrs["trainee"] for path in folder.glob("*.h5")}
    assert sorted(names.values()) == ["Other", "Trainee 7", "trainee 7"]  # as typed, surrounding spaces trimmed
    path = next(path for path, name in names.items() if name == "Trainee 7")
    outcome = replay_session(path)
    assert outcome.reproduced and outcome.refused_controls == 0


def test_placing_the_probe_measures_the_acquisition_error_and_scores_care(folder):
    rows = _by_error(of_trainee(summaries(session_files([folder])), "TRAINEE 7"))
    careful, careless = rows
    assert careful["metrics"]["landmarks_acquired"] == careless["metrics"]["landmarks_acquired"] == LANDMARKS
    assert careful["metrics"]["acquisition_error_mean_mm"] == pytest.approx(0.3, abs=0.2)
    assert careless["metrics"]["acquisition_error_mean_mm"] == pytest.approx(4.2, abs=0.2)
    points = [{c.name: c.points for c in build_assessment(folder / f"{r['session']}.h5").criteria} for r in (careful, careless)]
    assert points[0]["acquisition accuracy"] == 10 and points[1]["acquisition accuracy"] == 0
    assert careful["score"] > careless["score"]


def test_placing_is_refused_without_a_tip_or_far_off_and_nothing_changes():
    clock = FakeClock()
    session = LiveSession(MODES["navigation"], {"side": "right", "seed": 3}, clock, Path("/tmp"))
    try:
        for bad in ({"type": "probe", "action": "place"}, {"type": "probe", "action": "place", "tip_mm": [0, 0, 5e3]}):
            with pytest.raises(ThrsimInputError, match="tip_mm"):
                session.control(bad)
        assert "Probe" not in session.trainer.tools
        for bad_name in ("", " leading", "x" * 41, "a/b", "<script>"):
            with pytest.raises(ThrsimInputError, match="trainee control refused"):
                session.control({"type": "trainee", "id": bad_name})
        assert "trainee" not in session.attrs
    finally:
        session.discard()


def test_summaries_and_exports_have_one_row_per_session_with_the_metrics(folder):
    rows = summaries(session_files([folder]))
    assert [r["trainee"] for r in rows] == ["Trainee 7", "trainee 7 ".strip(), "Other"]
    table = list(csv.DictReader(io.StringIO(to_csv(rows))))
    assert len(table) == 3 and [t["session"] for t in table] == [r["session"] for r in rows]
    for column in (
        "trainee",
        "mode",
        "started_utc",
        "duration_s",
        "score",
        "acquisition_error_mean_mm",
        "registration_rms_mm",
        "q_bone_realism",
    ):
        assert column in table[0]
    assert float(table[0]["acquisition_error_mean_mm"]) == pytest.approx(rows[0]["metrics"]["acquisition_error_mean_mm"])
    data = to_json(rows)
    assert len(data["sessions"]) == 3 and data["competency"]["acquisition_error_mean_mm"] == [1.5, "max"]
    json.dumps(data, allow_nan=False)


def test_sessions_export_command_writes_csv_and_json_and_refuses_bad_input(folder, tmp_path, monkeypatch, capsys):
    code, out, err = run_main(monkeypatch, capsys, "sessions", "export", "--csv", str(folder))
    assert code == 0 and err == "" and len(list(csv.DictReader(io.StringIO(out)))) == 3
    target = tmp_path / "study.json"
    code, out, _ = run_main(
        monkeypatch, capsys, "sessions", "export", "--json", "--out", str(target), *map(str, sorted(folder.glob("*.h5"))[:2])
    )
    assert code == 0 and "2 sessions written" in out and len(json.loads(target.read_text())["sessions"]) == 2
    for args, said in (
        (("--csv", "--json", str(folder)), "one of them"),
        (("--csv", str(tmp_path / "none")), "no such session file or folder"),
        (("--json", str(target)), "unreadable session file"),
        (("--csv", "--thresholds", str(tmp_path / "none.yaml"), str(folder)), "cannot read the thresholds file"),
    ):
        code, out, err = run_main(monkeypatch, capsys, "sessions", "export", *args)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and said in err and "Traceback" not in err


def test_the_questionnaire_is_stored_with_the_session_and_exported(folder, tmp_path):
    path = sorted(folder.glob("*.h5"))[-1]
    copy = tmp_path / path.name
    copy.write_bytes(path.read_bytes())
    before = copy.read_bytes()
    for answers, comment, said in (
        ({"bone_realism": 6}, "", "from 1 to 5"),
        ({"bone_realism": 4.0}, "", "from 1 to 5"),
        ({"smell": 3}, "", "unknown questionnaire item"),
        ({}, "", "nothing answered"),
        ({"bone_realism": 3}, "x" * 2000, "at most"),
    ):
        with pytest.raises(ThrsimInputError, match=said):
            write_questionnaire(copy, answers, comment)
    assert copy.read_bytes() == before  # nothing written
    write_questionnaire(copy, {"bone_realism": 4, "training_usefulness": 5}, "=more\nbone  please")
    stored = read_questionnaire(read_session(copy))
    assert stored["answers"] == {"bone_realism": 4, "training_usefulness": 5} and stored["comment"] == "=more bone please"
    row = list(csv.DictReader(io.StringIO(to_csv(summaries([copy])))))[0]
    assert row["q_bone_realism"] == "4" and row["q_training_usefulness"] == "5" and row["q_force_realism"] == ""
    assert row["q_comment"] == "'=more bone please"  # text, not a formula, in a spreadsheet
    assert set(ITEMS) <= {k[2:] for k in row if k.startswith("q_")}
    assert build_assessment(copy).score == build_assessment(path).score  # the answers change no score


class _Client:
    """GET and POST over a real socket to a uvicorn server on 127.0.0.1 (urllib; no test transport)."""

    def __init__(self, url: str, folder: Path):
        self.url, self.folder = url, folder

    def request(self, path: str, body: bytes | None = None, headers: dict | None = None) -> tuple[int, str]:
        import urllib.error
        import urllib.request

        request = urllib.request.Request(self.url + path, data=body, headers=headers or {}, method="POST" if body is not None else "GET")
        try:
            with urllib.request.urlopen(request, timeout=30) as response:
                return response.status, response.read().decode()
        except urllib.error.HTTPError as error:
            return error.code, error.read().decode()

    def get(self, path: str) -> tuple[int, str]:
        return self.request(path)

    def post_json(self, path: str, payload: object, **headers: str) -> tuple[int, dict]:
        status, text = self.request(path, json.dumps(payload).encode(), {"content-type": "application/json", **headers})
        return status, json.loads(text)


@pytest.fixture
def client(folder, tmp_path):
    import socket
    import threading
    import time

    import uvicorn
    from fastapi import FastAPI

    from thrsim.app.sessions_pages import record_routes

    copies = tmp_path / "sessions"
    copies.mkdir()
    for path in folder.glob("*.h5"):
        (copies / path.name).write_bytes(path.read_bytes())
    app = FastAPI()
    for route, handler, methods in record_routes(copies):
        app.add_api_route(route, handler, methods=methods)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started
    yield _Client(f"http://127.0.0.1:{port}", copies)
    server.should_exit = True
    thread.join(10)


def test_the_session_list_the_trainee_page_and_the_exports_over_http(client):
    _, listing = client.get("/sessions")
    assert listing.count("<tr data-session=") == 3 and listing.count("/report") == 3 and 'href="/trainee/trainee%207"' in listing
    status, page = client.get("/trainee/Trainee%207")
    assert status == 200 and "<h1>Trainee trainee 7</h1>" in page and "2 sessions" in page  # named as in the latest session
    assert page.count('<figure data-metric="acquisition_error_mean_mm">') == 1
    chart = page.split('<figure data-metric="acquisition_error_mean_mm">')[1].split("</figure>")[0]
    assert chart.count('class="point"') == 2 and 'class="competency"' in chart and "competent: ≤ 1.5" in chart
    assert client.get("/trainee/nobody")[0] == 404 and client.get("/trainee/%3Cscript%3E")[0] == 404
    table = list(csv.DictReader(io.StringIO(client.get("/api/sessions.csv")[1])))
    assert len(table) == 3 and table[0]["acquisition_error_mean_mm"]
    assert len(json.loads(client.get("/api/sessions.json")[1])["sessions"]) == 3


def test_questionnaire_answers_over_http_are_stored_and_bad_ones_refused(client):
    session = sorted(client.folder.glob("*.h5"))[0].stem
    url = f"/api/sessions/{session}/questionnaire"
    assert set(json.loads(client.get("/api/questionnaire")[1])["items"]) == set(ITEMS)
    form = client.request(url, b"answers=x", {"content-type": "application/x-www-form-urlencoded"})  # what another site's form sends
    assert form[0] == 415
    assert client.post_json(url, {"answers": {"bone_realism": 3}}, origin="http://evil.example")[0] == 403
    status, refused = client.post_json(url, {"answers": {"bone_realism": 9}})
    assert status == 422 and "from 1 to 5" in refused["error"]
    assert client.post_json("/api/sessions/20260101T000000Z-abcdef/questionnaire", {"answers": {"bone_realism": 3}})[0] == 404
    status, saved = client.post_json(url, {"answers": {"bone_realism": 3, "force_realism": 2}, "comment": "ok"})
    assert status == 200 and saved["answers"] == {"bone_realism": 3, "force_realism": 2}
    row = next(r for r in csv.DictReader(io.StringIO(client.get("/api/sessions.csv")[1])) if r["session"] == session)
    assert row["q_bone_realism"] == "3" and row["q_force_realism"] == "2" and row["q_comment"] == "ok"


def test_a_session_a_crash_left_open_keeps_its_trainee(tmp_path):
    from thrsim.app.live import close_interrupted

    clock = FakeClock()
    session = LiveSession(MODES["navigation"], {"side": "right", "seed": 3}, clock, tmp_path)
    session.control({"type": "trainee", "id": "Night shift"})
    session.control({"type": "probe", "action": "touch"})
    for _ in range(60):
        clock.now += 1 / 60
        session.tick()
    session.journal.close()  # the server died: the journal stays, unlocked
    [closed] = close_interrupted(tmp_path)
    attrs = read_session(closed).attrs
    assert attrs["interrupted"] and attrs["trainee"] == "Night shift"
    assert summaries([closed])[0]["trainee"] == "Night shift"
