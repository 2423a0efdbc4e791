"""The navigation mode's group of a session file: orientation trace, tool states, registration,
calibration attempts and confirmed cup orientations — what the assessment report reads.

Group ``/navigation``: attrs ``side``, ``seed``, ``tools`` and ``tool_states`` (JSON lists
naming the codes in ``trace/tools``), ``zone`` and ``tracking`` (JSON settings); ``trace/``
``time``, ``angles`` (T×3: radiographic inclination, anteversion, distance to the safe zone,
degrees, NaN when the reamer was not measured), ``phase`` (0 registering, 1 aiming), ``tools``
(T×3 codes); ``events/`` ``time``, ``kind``, ``landmark``, ``detail``, ``value``;
``registration/`` ``names``, ``targets`` (N×3 m, reference frame), ``acquired`` (N×3, NaN when
not), ``residual_m`` (fit residual per landmark, NaN before the fit), ``time_s`` (per landmark,
NaN when not acquired), ``retakes`` (per landmark), attrs ``completed``, ``rms_m``;
``calibration`` attrs ``attempts`` (JSON list); ``confirmed`` attrs ``cups`` (JSON list).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import h5py
import numpy as np

from thrsim.errors import ThrsimInputError

_TEXT = h5py.string_dtype()


@dataclass
class NavigationRecord:
    side: str
    tools: list[str]
    tool_states: list[str]
    zone: dict
    time: np.ndarray
    angles: np.ndarray
    phase: np.ndarray
    tool_codes: np.ndarray
    events: list[dict]
    names: list[str]
    targets: np.ndarray
    acquired: np.ndarray
    residual_m: np.ndarray
    landmark_time_s: np.ndarray
    retakes: np.ndarray
    completed: bool
    rms_m: float
    calibrations: list[dict]
    confirmations: list[dict]

    @property
    def assessable(self) -> bool:
        """Whether there is anything to score: a landmark acquired, a cup confirmed or a calibration tried."""
        return bool(np.isfinite(self.acquired).any() or self.confirmations or self.calibrations)


def write_navigation(group: h5py.Group, record: NavigationRecord, settings: dict) -> None:
    group.attrs.update(
        side=record.side,
        tools=json.dumps(record.tools),
        tool_states=json.dumps(record.tool_states),
        zone=json.dumps(record.zone),
        settings=json.dumps(settings),
    )
    trace = group.create_group("trace")
    trace.create_dataset("time", data=np.asarray(record.time, dtype=float))
    trace.create_dataset("angles", data=np.asarray(record.angles, dtype=float).reshape(-1, 3))
    trace.create_dataset("phase", data=np.asarray(record.phase, dtype=np.int8))
    trace.create_dataset("tools", data=np.asarray(record.tool_codes, dtype=np.uint8).reshape(-1, len(record.tools)))
    events = group.create_group("events")
    events.create_dataset("time", data=np.array([e["time_s"] for e in record.events], dtype=float))
    for key in ("kind", "landmark", "detail"):
        events.create_dataset(key, data=np.array([e[key] or "" for e in record.events], dtype=object).astype(_TEXT))
    events.create_dataset("value", data=np.array([np.nan if e["value"] is None else e["value"] for e in record.events], dtype=float))
    registration = group.create_group("registration")
    registration.attrs.update(completed=record.completed, rms_m=record.rms_m)
    registration.create_dataset("names", data=np.array(record.names, dtype=object).astype(_TEXT))
    for key in ("targets", "acquired", "residual_m", "landmark_time_s", "retakes"):
        registration.create_dataset(key, data=getattr(record, key))
    group.create_group("calibration").attrs["attempts"] = json.dumps(record.calibrations)
    group.create_group("confirmed").attrs["cups"] = json.dumps(record.confirmations)


def read_navigation(group: dict) -> NavigationRecord:
    """The navigation group as read by :func:`thrsim.session.read_session` (nested dicts)."""
    try:
        attrs, trace, events, registration = group["attrs"], group["trace"], group["events"], group["registration"]

        def nan_to_none(value: float) -> float | None:
            return None if np.isnan(value) else float(value)

        return NavigationRecord(
            side=str(attrs["side"]),
            tools=json.loads(attrs["tools"]),
            tool_states=json.loads(attrs["tool_states"]),
            zone=json.loads(attrs["zone"]),
            time=np.asarray(trace["time"], dtype=float),
            angles=np.asarray(trace["angles"], dtype=float).reshape(-1, 3),
            phase=np.asarray(trace["phase"]),
            tool_codes=np.asarray(trace["tools"]),
            events=[
                {"time_s": float(t), "kind": k, "landmark": n or None, "detail": d, "value": nan_to_none(v)}
                for t, k, n, d, v in zip(events["time"], events["kind"], events["landmark"], events["detail"], events["value"], strict=True)
            ],
            names=list(registration["names"]),
            targets=np.asarray(registration["targets"], dtype=float),
            acquired=np.asarray(registration["acquired"], dtype=float),
            residual_m=np.asarray(registration["residual_m"], dtype=float),
            landmark_time_s=np.asarray(registration["landmark_time_s"], dtype=float),
            retakes=np.asarray(registration["retakes"], dtype=int),
            completed=bool(registration["attrs"]["completed"]),
            rms_m=float(registration["attrs"]["rms_m"]),
            calibrations=json.loads(group["calibration"]["attrs"]["attempts"]),
            confirmations=json.loads(group["confirmed"]["attrs"]["cups"]),
        )
    except (KeyError, TypeError, ValueError) as error:
        raise ThrsimInputError(f"session file's navigation group is incomplete or garbled ({error})") from None
