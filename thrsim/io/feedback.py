"""What the trainer sends back to its OpenIGTLink peers (``thrsim serve --igtl-feedback``).

The device names, defined here once: :data:`EVENT_DEVICE`, a STRING of each trainer step's events,
:data:`SIM_REAMER_DEVICE`, a TRANSFORM of the simulated reamer, and :data:`REACTION_DEVICE` and
:data:`TORQUE_DEVICE`, SENSORs of each frame's force (a whole-socket model's; the haptic stream,
:mod:`thrsim.io.haptic`, sends them too). Sending is opt-in: a peer
written for the reply-per-message protocol (one ``NavigationState`` per TRANSFORM or SENSOR) would
read an unsolicited message as that reply.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable

import numpy as np

from thrsim.io import igtl

#: a STRING at each trainer step that had events: ``{"events": [...]}``, each event as the session
#: file keeps it (``kind``, ``time_s`` from its session's start, ``detail``, its figures) with
#: ``session`` and ``mode``. One message per step, not per event: pyigtl and 3D Slicer keep only the
#: newest message of a device name, and a step often has two events (``acquired``, the next
#: ``target``). The kinds are the trainers' (``target``, ``acquired``, ``completed``,
#: ``tracking_lost``, ...; ``start``, ``pause``, ``reamer_changed``, ``perforated``,
#: ``medial_wall_breached``, ...) and :data:`SESSION_ENDED`.
EVENT_DEVICE = "thrsimEvent"
#: a TRANSFORM at every trainer step once the simulator has placed the reamer: the simulated reamer
#: in the bone patch's frame (origin at the acetabular centre, +z out of the acetabulum), rotation
#: whose local +z is the reamer axis D (into the bone), translation the head centre (mm on the
#: wire); at γ = 0 the rotation is diag(1, −1, −1)
SIM_REAMER_DEVICE = "SimReamerToBone"
#: the event sent when a live session ends (its trainee ended it or left): not one of the trainers' own
SESSION_ENDED = "session_ended"
#: a SENSOR per simulated frame of a whole-socket model: one value, the bone's reaction along the
#: reamer axis (N, unit field newton); a SENSOR has one unit field for all its values, so the torque,
#: in N·m, is its own SENSOR (:data:`TORQUE_DEVICE`), sent right after it
REACTION_DEVICE = "ReamerReaction"
#: a SENSOR per simulated frame: one value, the reamer's motor torque (N·m, unit field newton·metre)
TORQUE_DEVICE = "ReamerTorque"

Outgoing = tuple[str, str, bytes]  # type, device name, content


def events_message(events: list[dict]) -> Outgoing:
    """A step's events (each with its ``session`` and ``mode``) as one ``thrsimEvent`` STRING."""
    return "STRING", EVENT_DEVICE, igtl.pack_string(json.dumps({"events": events}, allow_nan=False))


def session_ended(session_id: str, mode: str, time_s: float, file: str | None) -> dict:
    """The event of a session's end: ``file`` is the session file's name, None when it was not saved."""
    return {"kind": SESSION_ENDED, "time_s": time_s, "detail": "", "file": file, "session": session_id, "mode": mode}


def reamer_to_bone(gamma_deg: float, theta_deg: float, centre_m: np.ndarray) -> np.ndarray:
    """4×4 pose of the reamer in the bone frame (metres): local +z along D = (sin γ cos θ, sin γ sin θ, −cos γ),
    the rotation Rz(θ)·Ry(−γ)·diag(1, −1, −1), translation the head centre."""
    gamma, theta = math.radians(gamma_deg), math.radians(theta_deg)
    about_z = np.array([[math.cos(theta), -math.sin(theta), 0.0], [math.sin(theta), math.cos(theta), 0.0], [0.0, 0.0, 1.0]])
    about_y = np.array([[math.cos(gamma), 0.0, -math.sin(gamma)], [0.0, 1.0, 0.0], [math.sin(gamma), 0.0, math.cos(gamma)]])
    pose = np.eye(4)
    pose[:3, :3] = about_z @ about_y @ np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = centre_m
    return pose


def step_events(session_id: str, states: Iterable[dict]) -> list[dict]:
    """Each event of one trainer step's states once, with its session and mode (a slow step hands out
    an early state first: both are given, and an event in both is one event)."""
    events: list[dict] = []
    seen: set[int] = set()
    for state in states:
        for fields in [*state.get("events", ()), *(state.get("reaming") or {}).get("events", ())]:
            if id(fields) not in seen:
                seen.add(id(fields))
                events.append({**fields, "session": session_id, "mode": state["mode"]})
    return events


def force_messages(reaction_n: float, motor_torque_n_m: float) -> list[Outgoing]:
    """The ``ReamerReaction`` and ``ReamerTorque`` SENSORs of one force, in their units."""
    return [
        ("SENSOR", REACTION_DEVICE, igtl.pack_sensor([reaction_n], igtl.UNIT_NEWTON)),
        ("SENSOR", TORQUE_DEVICE, igtl.pack_sensor([motor_torque_n_m], igtl.UNIT_NEWTON_METRE)),
    ]


def frame_forces(states: Iterable[dict]) -> list[Outgoing]:
    """The force SENSORs of every frame a trainer step simulated, in order (none without a whole-socket model)."""
    return [
        message
        for state in states
        for frame in (state.get("reaming") or {}).get("frame_forces", ())
        for message in force_messages(frame["reaction_n"], frame["motor_torque_n_m"])
    ]


def simulated_reamer(state: dict, scene: Callable[[], dict]) -> Outgoing | None:
    """The ``SimReamerToBone`` TRANSFORM of a step's state; None until the simulator has placed the
    reamer. ``scene`` (the trainer's) is asked only then, for the patch's placement in the pelvis model."""
    reaming = state.get("reaming") or {}
    centre, gamma, theta = reaming.get("reamer_centre"), reaming.get("gamma_deg"), reaming.get("theta_deg")
    if centre is None or gamma is None or theta is None:
        return None
    model_to_patch = np.linalg.inv(np.reshape(scene()["reaming"]["patch_to_model"], (4, 4)))
    in_bone = model_to_patch[:3, :3] @ np.asarray(centre, dtype=float) + model_to_patch[:3, 3]
    return "TRANSFORM", SIM_REAMER_DEVICE, igtl.pack_transform(reamer_to_bone(gamma, theta, in_bone))
