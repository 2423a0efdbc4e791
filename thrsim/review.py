"""The thesis's simulator review rubric [2.2.1, Tables 2–3] as data, with thrsim scored on it.

Nine requirements in three groups — immersion (a–c), response of the content to interaction
(d–f), applied learning theories (g–i) — each marked met (○), partially met (∩) or not met
(-); each group gets 0–5. The thesis states six cases of the group score: 0 none met; 1 one
partial, two not; 2 two partial, one not; 3 all partial; 4 two met and one partial; 5 all met.
Other combinations (e.g. one met, two not) are not listed; they are scored here by the count
of requirements addressed at least partially, plus 1 when all three are addressed and two are
met (the thesis's 4) and plus 2 when all three are met (its 5) — the rule the six cases follow.
"""

from __future__ import annotations

MET, PARTIAL, NOT_MET = "met", "partial", "not met"
_SYMBOL = {"○": MET, "∩": PARTIAL, "-": NOT_MET}

GROUPS: dict[str, tuple[str, ...]] = {
    "immersion": ("a", "b", "c"),
    "response to interaction": ("d", "e", "f"),
    "applied learning theories": ("g", "h", "i"),
}
CRITERIA: dict[str, str] = {
    "a": "field of view similar to the reality",
    "b": "realistic content rendering",
    "c": "the interaction feels natural (haptics and tools)",
    "d": "mesh deformation based on input forces and tool movements",
    "e": "interactive kinematic models to allow change of patient position",
    "f": "interaction with all rendered tissues",
    "g": "decision making allowed",
    "h": "modular (different tools and approaches to select from)",
    "i": "detailed and valuable assessment report",
}

# Table 3, row by row (a … i), with the simulator's category from the review's text.
THESIS_TABLE: dict[str, tuple[str, str, bool]] = {
    # name: (category, marks a–i, has a total hip replacement module)
    "OssoVR Osso": ("cognitive", "○○∩-∩∩∩-∩", True),
    "Blyth P. Virtual Reality simulator": ("cognitive", "∩∩--∩-∩-∩", True),
    "Touch Surgery": ("cognitive", "∩∩--∩----", True),
    "Simbionix - ArthroMentor": ("arthroscopy", "○∩∩○○∩∩∩∩", False),
    "Virtamed ArthroS": ("arthroscopy", "○○○○○○○○∩", False),
    "TraumaVision": ("open surgery", "○∩○∩∩∩--∩", False),
    "OsSim Tech": ("open surgery", "○○∩-∩∩∩○○", False),
    "Fundamental Surgery": ("open surgery", "○○∩∩∩∩∩-∩", True),
}

# thrsim's browser trainer as it is today, requirement by requirement, with the reason.
THRSIM: dict[str, tuple[str, str]] = {
    "a": (PARTIAL, "a 3-D scene the trainee orbits on a monitor or a headset's browser; not the surgeon's head-tracked view"),
    "b": (NOT_MET, "a stylised pelvis and tools with simple shading"),
    "c": (PARTIAL, "real tracked tools over OpenIGTLink, or mouse and keyboard; no haptics"),
    "d": (
        PARTIAL,
        "the reaming mode removes bone live from the push force and the reamer's pose (the shipped learned simulator); the bone does not visibly deform",
    ),
    "e": (NOT_MET, "the patient's position cannot be changed"),
    "f": (PARTIAL, "only the 27 landmark points respond to the probe"),
    "g": (PARTIAL, "camera placement, retakes and the confirmed cup orientation are the trainee's; no branching case"),
    "h": (PARTIAL, "left or right hip, three angle definitions, real or simulated tools; one procedure step"),
    "i": (MET, "every session ends with a scored report: registration, orientation against the safe zone, tracking dropouts"),
}


def group_score(marks: tuple[str, ...]) -> int:
    """0–5 for one group's three marks (met / partial / not met); see the module docstring."""
    if len(marks) != 3 or any(m not in (MET, PARTIAL, NOT_MET) for m in marks):
        raise ValueError(f"a group needs three marks among met, partial, not met; got {marks}")
    addressed = sum(m != NOT_MET for m in marks)
    met = sum(m == MET for m in marks)
    if addressed == 3 and met == 3:
        return 5
    if addressed == 3 and met == 2:
        return 4
    return addressed


def score(marks: dict[str, str]) -> dict[str, int]:
    """Group scores of one simulator from its marks per criterion (a–i)."""
    return {group: group_score(tuple(marks[c] for c in letters)) for group, letters in GROUPS.items()}


def review() -> dict:
    """The rubric, the thesis's reviewed simulators with their scores, and thrsim's."""
    simulators = {}
    for name, (category, symbols, hip) in THESIS_TABLE.items():
        marks = {c: _SYMBOL[s] for c, s in zip(CRITERIA, symbols, strict=True)}
        simulators[name] = {"category": category, "total_hip_replacement": hip, "marks": marks, "scores": score(marks)}
    own = {c: mark for c, (mark, _) in THRSIM.items()}
    return {
        "criteria": CRITERIA,
        "groups": {group: list(letters) for group, letters in GROUPS.items()},
        "simulators": simulators,
        "thrsim": {"marks": own, "reasons": {c: reason for c, (_, reason) in THRSIM.items()}, "scores": score(own)},
    }
