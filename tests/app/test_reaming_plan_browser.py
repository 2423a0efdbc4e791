"""The plan and the reamer sequence end to end, in a real headless Chromium against a real
``thrsim serve`` with the shipped model: the trainee sets a plan on the page, reams with one
reamer, swaps to the next with the key and to a third with the select, confirms the cup with
Enter, ends the session, and ``thrsim report --json`` measures it against the plan with the
sequence and its times."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from app_helpers import ServedTrainer, keys
from checkout_cli import run_main

from thrsim.app.drawing_bench import CHROMIUM, CHROMIUM_FLAGS
from thrsim.config import SafeZone
from thrsim.nav.anatomy import angles_from_local
from thrsim.nav.bone_frame import patch_in_app
from thrsim.session import read_session
from thrsim.session.reaming import read_reaming

pytestmark = [
    pytest.mark.skipif(shutil.which(CHROMIUM) is None, reason="Debian chromium is not installed (./install.sh installs it)"),
    pytest.mark.timeout(300),
]

PLAN = {"plan-cup": 50, "plan-inc": 42, "plan-ant": 18, "plan-med": 1, "plan-sup": 0.5}


def _ream(page, frames: int) -> None:
    """Start reaming, wait for ``frames`` more frames, pause."""
    start = page.evaluate("trainer.stats.last.reaming.frame")
    keys(page, "Space")
    page.wait_for_function(f"trainer.stats.last.reaming.frame >= {start + frames}", timeout=60_000)
    keys(page, "Space")
    page.wait_for_function("!trainer.stats.last.reaming.running", timeout=10_000)


def test_a_planned_session_with_three_reamers_is_measured_against_its_plan(tmp_path, monkeypatch, capsys):
    from playwright.sync_api import sync_playwright

    served = ServedTrainer(tmp_path, timeout=180.0)  # the shipped model; a loaded machine starts it slowly
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=[*CHROMIUM_FLAGS, "--no-first-run"])
            page = browser.new_page(viewport={"width": 1000, "height": 700})
            problems: list[str] = []
            page.on("pageerror", lambda error: problems.append(str(error)))
            page.goto(served.url + "/reaming", timeout=30_000)
            page.wait_for_function("window.trainer && trainer.stats.hello && trainer.stats.states > 5", timeout=60_000)
            assert page.evaluate("document.getElementById('reamer').textContent") == "44 mm"  # 4 mm under the default 48 mm cup
            for field, value in PLAN.items():
                page.fill(f"#{field}", str(value))
            page.click("#plan-set")
            page.wait_for_function("trainer.stats.last.reaming.plan.cup_diameter_mm === 50", timeout=10_000)
            keys(page, "BracketRight")  # 44 → 45 mm
            page.wait_for_function("trainer.stats.last.reaming.reamer.size_mm === 45", timeout=10_000)
            _ream(page, 20)
            assert page.evaluate("document.getElementById('plan-cup').disabled")  # the plan is fixed once reaming starts
            keys(page, "BracketRight")  # 46 mm
            page.wait_for_function("trainer.stats.last.reaming.reamer.size_mm === 46", timeout=10_000)
            _ream(page, 20)
            page.select_option("#reamer-size", "48")  # the select: 48 mm
            page.wait_for_function("trainer.stats.last.reaming.reamer.size_mm === 48", timeout=10_000)
            _ream(page, 20)
            shown = page.evaluate("[document.getElementById('reamer').textContent, document.getElementById('reamer-note').textContent]")
            keys(page, "Enter")  # confirm the cup along the reamer
            page.wait_for_function("trainer.stats.events.includes('cup_confirmed')", timeout=10_000)
            page.click("#end")
            page.wait_for_function("trainer.stats.saved", timeout=30_000)
            saved = page.evaluate("trainer.stats.saved")
            browser.close()
    finally:
        served.stop()
    assert problems == []
    assert shown[0] == "48 mm" and "the model was trained on 45.8 mm only" in shown[1]  # read from the shipped model's card

    code, out, err = run_main(monkeypatch, capsys, "report", saved["file"], "--json")
    assert code == 0, err
    report = json.loads(out)
    found = report["metrics"]
    assert found["plan"] == {
        "cup_diameter_mm": 50.0,
        "centre": {"medialisation_mm": 1.0, "superior_shift_mm": 0.5},
        "inclination_deg": 42.0,
        "anteversion_deg": 18.0,
        "source": "trainee",
    }
    record = read_reaming(read_session(saved["file"]).groups["reaming"])
    dt = record.frame_dt_s
    frames = [int(np.sum(record.reamer_mm == size)) for size in (45, 46, 48)]
    assert found["reamer_sequence_mm"] == [45.0, 46.0, 48.0] and min(frames) >= 20
    assert found["time_per_reamer_s"] == pytest.approx([n * dt for n in frames])
    swaps = [(e["kind"], e.get("from_mm"), e.get("to_mm")) for e in report["events"] if e["kind"] in ("plan_set", "reamer_changed")]
    assert swaps == [("plan_set", None, None), ("reamer_changed", 44, 45), ("reamer_changed", 45, 46), ("reamer_changed", 46, 48)]
    # the page aimed the reamer at the safe zone's centre, 40° and 15°: 2° and 3° off the plan, all the time within 5°
    aimed = angles_from_local(-(patch_in_app(SafeZone()) @ record.axis.mean(axis=0)))
    assert aimed == pytest.approx((40.0, 15.0), abs=0.5)
    assert found["inclination_error_deg"] == pytest.approx(abs(aimed[0] - 42.0), abs=0.3)
    assert found["anteversion_error_deg"] == pytest.approx(abs(aimed[1] - 18.0), abs=0.3)
    assert found["within_5deg_fraction"] == 1.0 and found["within_10deg_fraction"] == 1.0
    # the cup confirmed with Enter, the reamer still at the zone's centre: 2° and 3° off the plan
    assert found["confirmed_inclination_error_deg"] == pytest.approx(2.0, abs=1e-3)
    assert found["confirmed_anteversion_error_deg"] == pytest.approx(3.0, abs=1e-3)
    # the shipped model cut with its one reamer whatever was chosen: the cavity is 45.8 mm, 4.2 mm under the cup
    assert np.allclose(record.cut_mm, 45.8)
    assert found["cavity_diameter_mm"] == 45.8 and found["cavity_diameter_error_mm"] == pytest.approx(-4.2)
    # the cavity's centre: the reamer's at its deepest, in the pelvis's medial and superior directions
    cutting = np.flatnonzero(np.diff(record.removed_volume_mm3, prepend=0.0) > 0)  # no undo: every frame is the final bone's
    deepest = cutting[np.argmax(record.depth_mm[cutting])]
    lateral, _, inferior = patch_in_app(SafeZone()) @ record.position_m[deepest] * 1e3
    assert found["medialisation_mm"] == pytest.approx(-lateral) and found["superior_shift_mm"] == pytest.approx(-inferior)
    assert found["medial_wall_remaining_mm"] is None and found["perforations"] == 0 and found["undos"] == found["restores"] == 0
    named = {c["name"]: c for c in report["criteria"]}
    through = named["no perforation or breach"]["points"] == 0  # the shipped patch is 2 mm thick: a second of reaming may go through
    orientation = named["cavity orientation against the plan"]
    assert orientation["points"] == (0.0 if through else 2.0) and orientation["measured"].startswith("not a prepared") == through
    assert "45 → 46 → 48" in named["reamer sequence"]["measured"] and "cavity diameter against the plan" not in named
