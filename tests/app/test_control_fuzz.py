"""Property-based fuzz of the page's controls (issue 27, item 5).

Any JSON value, as text or decoded, and objects of every known control type whose fields hold any
JSON value, are either a control or refused with :class:`~thrsim.errors.ThrsimInputError` in one
short line, never another exception. End to end, a batch of random controls sent to ``thrsim
serve`` over a real WebSocket gets one reply each, one log line per refused control, no
traceback, and the session goes on.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import typing

import pytest
from app_helpers import ServedTrainer, next_of_type
from hypothesis import given, settings
from hypothesis import strategies as st
from websockets.sync.client import connect

from thrsim.app import controls
from thrsim.app.modes import MODES
from thrsim.errors import ThrsimInputError

PARSERS = {name: mode.parse_control for name, mode in MODES.items()}  # what the server calls on each frame
FIELDS = sorted({name for model in controls._REAMING for name in model.model_fields} - {"type"})

scalars = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20)
json_values = st.recursive(
    scalars, lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4), max_leaves=20
)
# fields a control might name, filled with any JSON value: most refused, some well-formed
control_objects = st.builds(
    lambda kind, fields, extra: {**fields, **extra, "type": kind},
    st.sampled_from(controls.REAMING_CONTROL_TYPES) | json_values,
    st.dictionaries(
        st.sampled_from(FIELDS), json_values | st.sampled_from(["touch", "start", "right", "operative"]) | st.floats(-200, 4000), max_size=4
    ),
    st.dictionaries(st.text(max_size=12), json_values, max_size=1),
)


def _values_of(annotation) -> st.SearchStrategy:
    """Values of a control field's type, in its range and out of it (NaN and ±inf included)."""
    if typing.get_origin(annotation) is typing.Literal:
        return st.sampled_from(typing.get_args(annotation))
    if annotation is float:
        return st.floats(0, 90) | st.floats(-200, 4000) | st.integers(-200, 4000) | st.floats() | st.integers(-(10**400), 10**400)
    if annotation is int:
        return st.integers(30, 70) | st.integers(-(10**400), 10**400) | st.floats(30, 70)
    if annotation is bool:
        return st.booleans()
    if annotation == list[float]:
        return st.lists(st.floats(-10, 10), min_size=16, max_size=16) | st.lists(st.floats(), min_size=15, max_size=17)
    if annotation == str | None:
        return st.none() | st.text(max_size=70)
    if annotation == list[float] | None:  # a placed probe tip (mm)
        return st.none() | st.lists(st.floats(-1500, 1500), min_size=3, max_size=3) | st.lists(st.floats(), min_size=2, max_size=4)
    if annotation is str:  # a trainee's name
        return st.text(max_size=50) | st.from_regex(r"[A-Za-z0-9][A-Za-z0-9 ._-]{0,45}", fullmatch=True)
    raise AssertionError(f"no strategy for a control field of type {annotation}: add one")


# every control type with fields of their own type, in range and out of it: many parse
typed_controls = st.one_of(
    [
        st.fixed_dictionaries({name: _values_of(field.annotation) for name, field in model.model_fields.items()})
        for model in controls._REAMING
    ]
)


def _parsed_or_refused(parse, message) -> object | None:
    """The control, or None when refused with ThrsimInputError in one short line; any other exception fails the test."""
    try:
        control = parse(message)
    except ThrsimInputError as error:
        text = str(error)
        assert text and "\n" not in text and "\r" not in text and len(text) <= 300, text
        return None
    for value in control.model_dump().values():  # what is accepted is finite
        assert not (isinstance(value, float) and not math.isfinite(value))
    return control


@pytest.mark.parametrize("mode", sorted(PARSERS))
@settings(max_examples=300)
@given(value=json_values)
def test_any_json_value_is_a_control_or_refused(mode, value):
    _parsed_or_refused(PARSERS[mode], value)
    _parsed_or_refused(PARSERS[mode], json.dumps(value))


@pytest.mark.parametrize("mode", sorted(PARSERS))
@settings(max_examples=500)
@given(message=control_objects)
def test_any_control_shaped_object_is_a_control_or_refused(mode, message):
    parsed = _parsed_or_refused(PARSERS[mode], message)
    assert _parsed_or_refused(PARSERS[mode], json.dumps(message)) == parsed


@pytest.mark.parametrize("mode", sorted(PARSERS))
@settings(max_examples=300)
@given(message=typed_controls)
def test_any_well_typed_control_is_a_control_or_refused(mode, message):
    parsed = _parsed_or_refused(PARSERS[mode], message)
    with contextlib.suppress(ValueError):  # an integer of more digits than Python converts to text
        assert _parsed_or_refused(PARSERS[mode], json.dumps(message)) == parsed


@settings(max_examples=200)
@given(text=st.text(max_size=200) | st.binary(max_size=200))
def test_any_text_or_bytes_is_a_control_or_refused(text):
    _parsed_or_refused(controls.parse_reaming_control, text)


def _as_text(value: object) -> str | None:
    """A WebSocket text frame of ``value`` (None for an integer Python will not write out)."""
    try:
        return json.dumps(value)
    except ValueError:
        return None


# what a page, or anything else that reaches the socket, might send; end_session is left out (the
# session must go on) and has tests of its own (test_session_journal.py, test_trainer_server.py)
frames = (typed_controls | control_objects).filter(lambda c: c.get("type") != "end_session").map(_as_text).filter(bool) | st.text(
    max_size=40
)


def _reply(ws, timeout: float = 30.0) -> dict:
    """The reply to the control just sent (an ack or an error), skipping the state stream."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        raw = ws.recv(timeout=max(0.01, deadline - time.monotonic()))
        if isinstance(raw, str) and (message := json.loads(raw))["type"] in ("ack", "error"):
            return message
    raise AssertionError("no reply to a control")


@pytest.mark.timeout(240)
@pytest.mark.parametrize("mode", sorted(PARSERS))
def test_random_controls_over_a_websocket_are_answered_and_logged_in_one_line_each(tmp_path, mode):
    served = ServedTrainer(tmp_path)
    refused = 0
    try:
        with connect(f"ws://127.0.0.1:{served.port}/ws/{mode}", open_timeout=10, max_size=None) as ws:
            session = next_of_type(ws, "hello")["session"]

            @settings(max_examples=6, database=None)
            @given(batch=st.lists(frames, min_size=10, max_size=10))
            def send(batch):
                nonlocal refused
                for frame in batch:
                    ws.send(frame)
                    refused += _reply(ws)["type"] == "error"

            send()
            ws.send(json.dumps({"type": "camera", "azimuth_deg": 30, "elevation_deg": 20, "distance_mm": 1500}))
            assert _reply(ws)["type"] == "ack"  # the session goes on
            assert next_of_type(ws, "state")["session"]["id"] == session
    finally:
        served.stop()
    log = served.stderr()
    assert "Traceback" not in log, log[-3000:]
    assert refused and len([line for line in log.splitlines() if f"{mode} control refused" in line]) == refused
