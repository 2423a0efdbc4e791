"""Control messages whose values are of the wrong JSON type, not finite, too long or nested too
deeply are refused with one line, on the page and in the server log, never a traceback (issue 27,
items 6 and 7: ``"200"`` and ``true`` were taken as a force)."""

from __future__ import annotations

import json

import pytest
from app_helpers import ServedTrainer, next_of_type
from websockets.sync.client import connect

from thrsim.app.controls import parse_reaming_control
from thrsim.errors import ThrsimInputError

BAD = {
    "force_as_text": ('{"type": "force", "newton": "200"}', "valid number"),
    "force_as_boolean": ('{"type": "force", "newton": true}', "valid number"),
    "force_nan": ('{"type": "force", "newton": NaN}', "finite"),
    "force_infinite": ('{"type": "force", "newton": 1e999}', "finite"),
    "force_of_5000_digits": ('{"type": "force", "newton": ' + "9" * 5000 + "}", "too many digits"),
    "json_8000_deep": ("[" * 8000 + "]" * 8000, "nests too deeply"),
    "field_8000_deep": ('{"type": "force", "newton": ' + "[" * 8000 + "]" * 8000 + "}", "nests too deeply"),
    "boolean_as_number": ('{"type": "occluder", "present": 1}', "valid boolean"),
    "angle_as_text": ('{"type": "reamer", "inclination_deg": "40", "anteversion_deg": 15}', "valid number"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_control_of_the_wrong_type_or_size_is_refused(case):
    text, needle = BAD[case]
    with pytest.raises(ThrsimInputError, match=needle):
        parse_reaming_control(text)


def test_numbers_are_still_numbers():
    assert parse_reaming_control('{"type": "force", "newton": 200}').newton == 200.0
    assert parse_reaming_control('{"type": "reamer", "inclination_deg": 40, "anteversion_deg": 15.5}').anteversion_deg == 15.5
    assert parse_reaming_control({"type": "occluder", "present": True}).present is True


@pytest.mark.timeout(120)
def test_the_server_answers_and_logs_each_bad_control_in_one_line(tmp_path):
    served = ServedTrainer(tmp_path)
    try:
        with connect(f"ws://127.0.0.1:{served.port}/ws/reaming", open_timeout=10, max_size=None) as ws:
            next_of_type(ws, "hello")
            for case in sorted(BAD):
                ws.send(BAD[case][0])
                assert BAD[case][1] in next_of_type(ws, "error")["message"]
            ws.send(json.dumps({"type": "force", "newton": 150}))
            assert next_of_type(ws, "ack")
    finally:
        served.stop()
    log = served.stderr()
    assert "Traceback" not in log
    assert len([line for line in log.splitlines() if "control refused" in line]) == len(BAD)
