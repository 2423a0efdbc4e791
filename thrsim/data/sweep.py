"""Sweep planning: angle lists, the case grid, γ = 0 deduplication, the push-force axis, splits.

Lists are comma-separated values and ``start:stop:step`` ranges, stop included, mixed freely
(:func:`parse_list`). γ = 0: the reamer axis D = (sin γ cos θ, sin γ sin θ, −cos γ) is (0, 0, −1)
whatever θ, so every γ = 0 case of one force and element size is one physical case: it is run
once, recorded with θ = 0, and the anteversions it stands for are listed in the manifest
(``aliases``). The default sweep's numbers are :class:`thrsim.config.SweepConfig`'s (60 cases).
The split is by orientation only, so a test orientation is never seen in training
(:class:`SplitRule`).
"""

from __future__ import annotations

import math
import random
from dataclasses import asdict, dataclass, field
from typing import Any

from thrsim.config import CANCELLOUS_PRESETS, ReamingCaseConfig, SocketSweepConfig, SweepConfig, head_diameter_for_size, teeth_for_diameter
from thrsim.errors import ThrsimInputError
from thrsim.geometry.socket import window_area_mm2

DEFAULTS = SweepConfig()
DEFAULT_INCLINATIONS = DEFAULTS.inclinations_deg
DEFAULT_ANTEVERSIONS = DEFAULTS.anteversions_deg
DEFAULT_FORCES_N = DEFAULTS.forces_n
DEFAULT_EXTRA_FORCES_N = DEFAULTS.extra_forces_n
DEFAULT_EXTRA_FORCE_ANTEVERSIONS = DEFAULTS.extra_force_anteversions_deg
DEFAULT_FRAMES = DEFAULTS.frames
SPLITS = ("train", "validation", "test")


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ThrsimInputError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ThrsimInputError(f"{what}: {text!r} is not a finite number")
    return value


def parse_list(text: str | None, what: str, *, allow_empty: bool = False) -> tuple[float, ...]:
    """Parse '0,15,30', '0:180:15' (stop included) or a mix; sorted, duplicates dropped."""
    if text is None:
        return ()
    text = text.strip()
    if text.lower() in ("", "none", "-"):
        if allow_empty:
            return ()
        raise ThrsimInputError(f"{what}: empty list")
    values: list[float] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            raise ThrsimInputError(f"{what}: empty item in {text!r}")
        if ":" in part:
            bits = part.split(":")
            if len(bits) != 3:
                raise ThrsimInputError(f"{what}: range {part!r} must be start:stop:step")
            start, stop, step = (_number(b, what) for b in bits)
            if step <= 0:
                raise ThrsimInputError(f"{what}: range {part!r} needs a positive step")
            if stop < start:
                raise ThrsimInputError(f"{what}: range {part!r} has stop below start")
            count = int(math.floor((stop - start) / step + 1e-9)) + 1
            if count > 100_000:
                raise ThrsimInputError(f"{what}: range {part!r} has {count} values; too many")
            values.extend(round(start + i * step, 9) for i in range(count))
        else:
            values.append(_number(part, what))
    return tuple(sorted(set(values)))


def format_list(values: tuple[float, ...]) -> str:
    """The inverse of :func:`parse_list`: '0,15,30,45' or, for an even run of five or more, '0:180:15'."""
    values = tuple(sorted(set(float(v) for v in values)))
    if not values:
        return "none"
    if len(values) >= 5:
        step = values[1] - values[0]
        if step > 0 and all(math.isclose(b - a, step, abs_tol=1e-9) for a, b in zip(values, values[1:], strict=False)):
            return f"{values[0]:g}:{values[-1]:g}:{step:g}"
    return ",".join(f"{v:g}" for v in values)


def _key(value: float) -> float:
    return round(float(value), 6)


@dataclass(frozen=True)
class CaseSpec:
    """One physical case of a sweep."""

    inclination_deg: float
    anteversion_deg: float
    force_n: float
    frames: int
    element_size_mm: float | None = None  # None: the configuration's default
    aliases: tuple[float, ...] = ()  # requested anteversions this case stands for (γ = 0)
    #: further case settings, dotted (``socket.window_polar_deg``) → value, and the name they give the case
    settings: tuple[tuple[str, Any], ...] = ()
    label: str = ""
    split: str | None = None  # set by a plan that decides the split itself (the socket's)

    def __post_init__(self) -> None:
        object.__setattr__(self, "aliases", tuple(self.aliases))
        object.__setattr__(self, "settings", tuple((str(k), _frozen(v)) for k, v in self.settings))

    @property
    def case_id(self) -> str:
        if self.label:
            return self.label
        name = f"g{self.inclination_deg:05.1f}_t{self.anteversion_deg:05.1f}_f{self.force_n:g}N"
        if self.element_size_mm is not None:
            name += f"_h{self.element_size_mm:g}mm"
        return name

    @property
    def orientation(self) -> tuple[float, float]:
        return (_key(self.inclination_deg), _key(self.anteversion_deg))

    def params(self) -> dict:
        data = asdict(self)
        data["aliases"] = list(self.aliases)
        data["settings"] = [[key, _thawed(value)] for key, value in self.settings]
        return data

    def case_config(self, template: dict | None = None) -> ReamingCaseConfig:
        """The full solver configuration of this case: the template with this case's axes set."""
        data = dict(template or {})
        data.update(
            inclination_deg=self.inclination_deg,
            anteversion_deg=self.anteversion_deg,
            force_n=self.force_n,
            frames=self.frames,
        )
        if self.element_size_mm is not None:
            bone = dict(data.get("bone") or {})
            bone["element_size_mm"] = self.element_size_mm
            data["bone"] = bone
        for dotted, value in self.settings:
            *parents, leaf = dotted.split(".")
            tree = data
            for key in parents:
                tree[key] = dict(tree.get(key) or {})
                tree = tree[key]
            tree[leaf] = _thawed(value)
        return ReamingCaseConfig.model_validate(data)


@dataclass(frozen=True)
class SplitRule:
    """Train/validation/test by orientation; γ = 0 (one physical case) trains by default.

    All forces and element sizes of one orientation share its split. By default, test: θ ∈ {45°,
    135°} for γ > 0 (6 orientations of the default grid); validation: θ = 90° for γ > 0 (3);
    train: everything else, the single γ = 0 case included (31). Orientations off the 15° grid
    follow the same rule (their θ is in neither set, so they train)."""

    test_anteversions_deg: tuple[float, ...] = (45.0, 135.0)
    validation_anteversions_deg: tuple[float, ...] = (90.0,)
    zero_inclination_split: str = "train"

    def split(self, inclination_deg: float, anteversion_deg: float) -> str:
        if _key(inclination_deg) == 0.0:
            return self.zero_inclination_split
        theta = _key(anteversion_deg)
        if theta in {_key(a) for a in self.test_anteversions_deg}:
            return "test"
        if theta in {_key(a) for a in self.validation_anteversions_deg}:
            return "validation"
        return "train"

    def of(self, spec: CaseSpec) -> str:
        """The split of a case: the plan's own choice when it made one, else by orientation."""
        return spec.split or self.split(spec.inclination_deg, spec.anteversion_deg)

    def as_dict(self) -> dict:
        return {
            "test_anteversions_deg": list(self.test_anteversions_deg),
            "validation_anteversions_deg": list(self.validation_anteversions_deg),
            "zero_inclination_split": self.zero_inclination_split,
        }


DEFAULT_SPLIT = SplitRule()


@dataclass
class SweepPlan:
    cases: list[CaseSpec]
    notes: list[str] = field(default_factory=list)
    requested: int = 0  # grid points before γ = 0 merging
    main_forces_n: tuple[float, ...] = DEFAULT_FORCES_N  # the forces of the full grid (the rest are extra)
    #: the dataset's frame count where its cases differ (the socket's long whole sockets ask more); None: the one all ask
    frames: int | None = None


def plan_sweep(
    inclinations: tuple[float, ...] = DEFAULT_INCLINATIONS,
    anteversions: tuple[float, ...] = DEFAULT_ANTEVERSIONS,
    *,
    frames: int = DEFAULT_FRAMES,
    force_n: float | tuple[float, ...] = DEFAULT_FORCES_N,
    extra_forces_n: tuple[float, ...] = DEFAULT_EXTRA_FORCES_N,
    extra_force_anteversions: tuple[float, ...] = DEFAULT_EXTRA_FORCE_ANTEVERSIONS,
    element_sizes_mm: tuple[float | None, ...] = (None,),
) -> SweepPlan:
    """The physical cases of a sweep: the full grid at the main force(s), extra forces on a subset.

    The subset for ``extra_forces_n`` is the grid's orientations whose anteversion is in
    ``extra_force_anteversions`` (every inclination). γ = 0 orientations merge into one case.
    """
    if not inclinations:
        raise ThrsimInputError("the sweep has no cases: no inclinations given")
    if not anteversions:
        raise ThrsimInputError("the sweep has no cases: no anteversions given")
    bad = [v for v in inclinations if not 0 <= v <= 90]
    if bad:
        raise ThrsimInputError(f"inclinations must lie in [0, 90] degrees, got {bad[0]:g}")
    bad = [v for v in anteversions if not 0 <= v <= 360]
    if bad:
        raise ThrsimInputError(f"anteversions must lie in [0, 360] degrees, got {bad[0]:g}")
    main_forces = (force_n,) if isinstance(force_n, (int, float)) else tuple(force_n)
    if not main_forces:
        raise ThrsimInputError("the sweep has no cases: no push force given")
    for f in main_forces + tuple(extra_forces_n):
        if not (math.isfinite(f) and f > 0):
            raise ThrsimInputError(f"push forces must be positive newtons, got {f:g}")
    if frames < 1:
        raise ThrsimInputError(f"must be at least 1, got {frames}", "frames")
    sizes = tuple(element_sizes_mm) or (None,)
    for h in sizes:
        if h is not None and not (math.isfinite(h) and h > 0):
            raise ThrsimInputError(f"element sizes must be positive millimetres, got {h:g}")

    grid = [(float(g), float(t)) for g in sorted(set(inclinations)) for t in sorted(set(anteversions))]
    subset_keys = {_key(a) for a in extra_force_anteversions}
    wanted: list[tuple[float, float, float]] = [(g, t, f) for f in main_forces for g, t in grid]
    wanted += [
        (g, t, f) for f in extra_forces_n if _key(f) not in {_key(m) for m in main_forces} for g, t in grid if _key(t) in subset_keys
    ]

    cases: dict[str, CaseSpec] = {}
    aliases: dict[str, list[float]] = {}
    for h in sizes:
        for g, t, f in wanted:
            theta = 0.0 if _key(g) == 0.0 else t
            spec = CaseSpec(inclination_deg=g, anteversion_deg=theta, force_n=float(f), frames=int(frames), element_size_mm=h)
            aliases.setdefault(spec.case_id, [])
            if t not in aliases[spec.case_id]:
                aliases[spec.case_id].append(t)
            cases.setdefault(spec.case_id, spec)
    planned = []
    notes = []
    for case_id, spec in cases.items():
        merged = tuple(sorted(aliases[case_id]))
        if _key(spec.inclination_deg) == 0.0:
            spec = CaseSpec(**{**spec.__dict__, "aliases": merged})
            if len(merged) > 1:
                notes.append(
                    f"γ = 0: anteversions {', '.join(f'{a:g}' for a in merged)} at {spec.force_n:g} N are one physical case "
                    f"(the reamer axis does not depend on θ); run once as {spec.case_id}"
                )
        planned.append(spec)
    if not planned:
        raise ThrsimInputError("the sweep has no cases")
    return SweepPlan(cases=planned, notes=notes, requested=len(wanted) * len(sizes), main_forces_n=tuple(float(f) for f in main_forces))


def coverage_order(cases: list[CaseSpec], main_forces_n: tuple[float, ...] = DEFAULT_FORCES_N) -> list[CaseSpec]:
    """The order cases are run in: a sweep cut short (a session's end, a kill) still covers
    every inclination, the split sets and the force axis, instead of one inclination's row.

    Anteversions go in a spread order (0, 180, 90, 45, 135, ...: each next one the furthest
    from those already taken), every inclination within one; the extra-force cases are
    interleaved evenly with the main-force ones (``main_forces_n``: the plan's).
    """
    thetas = sorted({c.anteversion_deg for c in cases})
    spread: list[float] = []
    while len(spread) < len(thetas):
        remaining = [t for t in thetas if t not in spread]
        spread.append(max(remaining, key=lambda t: (min((abs(t - s) for s in spread), default=math.inf), -t)))
    rank = {t: i for i, t in enumerate(spread)}

    def key(c: CaseSpec) -> tuple:
        return (rank[c.anteversion_deg], c.force_n, c.inclination_deg, c.element_size_mm or 0.0)

    is_main = {_key(f) for f in main_forces_n}
    main = sorted((c for c in cases if _key(c.force_n) in is_main), key=key)
    extra = sorted((c for c in cases if _key(c.force_n) not in is_main), key=key)
    position = {id(c): i / len(main) for i, c in enumerate(main)}
    position.update({id(c): (j + 0.5) / len(extra) for j, c in enumerate(extra)})
    return sorted(cases, key=lambda c: position[id(c)])


def _frozen(value: Any) -> Any:
    """Lists (JSON's tuples) as tuples, so a spec read back from a manifest equals the planned one."""
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    return value


def _thawed(value: Any) -> Any:
    if isinstance(value, tuple) and value and all(isinstance(v, tuple) and len(v) == 2 and isinstance(v[0], str) for v in value):
        return {k: _thawed(v) for k, v in value}
    if isinstance(value, tuple):
        return [_thawed(v) for v in value]
    return value


@dataclass(frozen=True)
class SocketSplitRule:
    """The socket plan decides each case's split (:func:`plan_socket_sweep`); this records what it held out."""

    config: SocketSweepConfig = SocketSweepConfig()

    def of(self, spec: CaseSpec) -> str:
        return spec.split or "train"

    def as_dict(self) -> dict:
        c = self.config
        return {
            "test_reamer_sizes_mm": list(c.test_reamer_sizes_mm),
            "test_anteversions_deg": list(c.test_anteversions_deg),
            "test_feeds_mm_s": list(c.test_feeds_mm_s),
            "validation_anteversions_deg": list(c.validation_anteversions_deg),
        }


class _Balanced:
    """Draws from a list so each value comes about equally often: shuffled rounds through the values."""

    def __init__(self, values, rng: random.Random):
        self.values, self.rng = list(values), rng
        self.queue: list[Any] = []

    def draw(self):
        if not self.queue:
            self.queue = self.values[:]
            self.rng.shuffle(self.queue)
        return self.queue.pop()


def plan_socket_sweep(config: SocketSweepConfig | None = None) -> SweepPlan:
    """The 0.5 dataset's cases (see :class:`thrsim.config.SocketSweepConfig`): windows of the socket, one
    reamer step each, at a prescribed feed; train, validation and test drawn apart, reproducibly."""
    config = config or SocketSweepConfig()
    rng = random.Random(config.seed)
    train_steps = [s for s in config.steps if s[2] not in config.test_reamer_sizes_mm]
    test_steps = [s for s in config.steps if s[2] in config.test_reamer_sizes_mm]
    tilted = [g for g in config.inclinations_deg if g > 0]
    fed_cases = config.train_cases + config.validation_cases + config.test_cases
    if fed_cases and (not config.train_cases or not train_steps or not tilted):
        raise ThrsimInputError("set-feed socket cases need train_cases, a reamer step to train on and a tilt above 0°")
    if (
        not fed_cases
        and not (config.pushed_windows and config.push_pressures_n_mm2)
        and not (config.whole_sockets or config.prepared_whole_sockets or config.long_whole_sockets)
    ):
        raise ThrsimInputError("the socket plan has no case: give set-feed cases (train_cases), pushed windows or whole sockets")
    axes = {
        "step": _Balanced(train_steps, rng),
        "polar": _Balanced(config.window_polars_deg, rng),
        "azimuth": _Balanced(config.window_azimuths_deg, rng),
        "inclination": _Balanced(config.inclinations_deg, rng),
        "anteversion": _Balanced(config.anteversions_deg, rng),
        "centre": _Balanced(config.reamer_centres_mm, rng),
        "feed": _Balanced(config.feeds_mm_s, rng),
        "cancellous": _Balanced(config.cancellous, rng),
    }
    held_out = [("step", s) for s in test_steps] + [("anteversion", t) for t in config.test_anteversions_deg]
    held_out += [("feed", f) for f in config.test_feeds_mm_s]
    held = _Balanced(held_out, rng)
    validation_direction = _Balanced(config.validation_anteversions_deg, rng)
    tilt = _Balanced(tilted, rng)
    cases: dict[str, CaseSpec] = {}
    for split, count in (("train", config.train_cases), ("validation", config.validation_cases), ("test", config.test_cases)):
        made = 0
        while made < count:
            pick = {name: axis.draw() for name, axis in axes.items()}
            if split == "validation":
                pick["inclination"], pick["anteversion"] = tilt.draw(), validation_direction.draw()
            if split == "test":
                name, value = held.draw()
                pick[name] = value
                if name == "anteversion":
                    pick["inclination"] = tilt.draw()
            spec = _socket_case(config, split, pick)
            if spec.case_id in cases:
                continue  # a repeat draw: draw again
            cases[spec.case_id] = spec
            made += 1
    pushed = [_pushed_case(config, window, pressure) for window in config.pushed_windows for pressure in config.push_pressures_n_mm2]
    cases.update((spec.case_id, spec) for spec in pushed)
    whole = [
        _whole_socket_case(config, size, *entry)
        for size in config.whole_socket_element_sizes_mm
        for entry in [(w[0], None, *w[1:]) for w in config.whole_sockets] + list(config.prepared_whole_sockets)
    ]
    long = [
        _whole_socket_case(config, config.whole_socket_element_sizes_mm[0], *entry, frames=config.long_whole_socket_frames)
        for entry in config.long_whole_sockets
    ]
    cases.update((spec.case_id, spec) for spec in whole + long)
    pushed_tests = sum(spec.split == "test" for spec in pushed)
    notes = [
        f"{config.train_cases} train, {config.validation_cases} validation, {config.test_cases} test window cases (seed {config.seed})",
        f"{len(pushed)} pushed windows ({len(pushed) - pushed_tests} train, {pushed_tests} test)",
        f"{len(whole)} pushed whole sockets at {format_list(config.whole_socket_element_sizes_mm)} mm ({', '.join(s.split or '' for s in whole) or 'none'})",
        f"{len(long)} long pushed whole sockets, {config.long_whole_socket_frames} frames at {config.whole_socket_element_sizes_mm[0]:g} mm"
        f" ({', '.join(s.split or '' for s in long) or 'none'})",
    ]
    return SweepPlan(
        cases=list(cases.values()),
        notes=notes,
        requested=len(cases),
        main_forces_n=(ReamingCaseConfig.model_fields["force_n"].default,),
        frames=config.frames,
    )


def window_push_n(config: SocketSweepConfig, socket_mm: float, pressure_n_mm2: float) -> float:
    """The push (N, to 0.1 N) that puts ``pressure_n_mm2`` on a window of the native socket."""
    return round(pressure_n_mm2 * window_area_mm2(socket_mm / 2.0, config.window_half_angle_deg), 1)


def _reamer(reamer_mm: float) -> list[tuple[str, Any]]:
    """The settings of a reamer of this size: its head and its teeth (by the size; stated, so a
    template dumped from another size does not keep its tooth count)."""
    head_mm = head_diameter_for_size(reamer_mm)
    return [("reamer.head_diameter_mm", head_mm), ("reamer.tooth_count", teeth_for_diameter(head_mm))]


def _pushed_case(config: SocketSweepConfig, window: tuple[float, float, float, float], pressure_n_mm2: float) -> CaseSpec:
    """A pushed window: the reamer along the socket's axis, driven by a set pressure over the window."""
    polar, azimuth, socket_mm, reamer_mm = (float(v) for v in window)
    azimuth = 0.0 if polar == 0.0 else azimuth
    settings: list[tuple[str, Any]] = [
        ("socket.socket_diameter_mm", socket_mm),
        ("socket.window_polar_deg", polar),
        ("socket.window_azimuth_deg", azimuth),
        ("socket.window_half_angle_deg", config.window_half_angle_deg),
        *_reamer(reamer_mm),
    ]
    split = "test" if (polar, azimuth) in {(float(p), float(a)) for p, a in config.test_pushed_windows} else "train"
    return CaseSpec(
        inclination_deg=0.0, anteversion_deg=0.0, force_n=window_push_n(config, socket_mm, pressure_n_mm2),
        frames=config.frames, settings=tuple(settings), label=f"s{socket_mm:g}_n_r{reamer_mm:g}_w{polar:g}a{azimuth:g}_push{pressure_n_mm2:g}",
        split=split,
    )  # fmt: skip


def _whole_socket_case(
    config: SocketSweepConfig,
    size: float,
    socket_mm: float,
    prepared_mm: float | None,
    reamer_mm: float,
    gamma: float,
    theta: float,
    push_n: float,
    split: str,
    frames: int | None = None,
) -> CaseSpec:
    """A pushed whole socket: the socket meshed whole at ``size`` mm, native or prepared to ``prepared_mm``,
    the reamer driven by a set push for the plan's frames or ``frames`` (a long case, named by them)."""
    theta = 0.0 if gamma == 0.0 else float(theta)
    settings: list[tuple[str, Any]] = [
        ("socket.socket_diameter_mm", float(socket_mm)),
        ("socket.window_polar_deg", None),
        ("socket.element_size_mm", size),
        *_reamer(float(reamer_mm)),
    ]
    if prepared_mm is not None:
        settings.append(("pre_ream_mm", float(prepared_mm)))
    prepared = "" if prepared_mm is None else f"_p{prepared_mm:g}"
    long = "" if frames is None else f"_f{frames}"
    return CaseSpec(
        inclination_deg=float(gamma), anteversion_deg=theta, force_n=float(push_n), frames=frames or config.frames,
        settings=tuple(settings), label=f"whole_s{socket_mm:g}{prepared}_r{reamer_mm:g}_g{gamma:g}t{theta:g}_F{push_n:g}_h{size:g}{long}",
        split=split,
    )  # fmt: skip


def _socket_case(config: SocketSweepConfig, split: str, pick: dict) -> CaseSpec:
    socket_mm, prepared_mm, reamer_mm = pick["step"]
    gamma = float(pick["inclination"])
    theta = 0.0 if gamma == 0.0 else float(pick["anteversion"])
    polar = float(pick["polar"])
    azimuth = 0.0 if polar == 0.0 else float(pick["azimuth"])
    centre = tuple(float(v) for v in pick["centre"])
    settings: list[tuple[str, Any]] = [
        ("socket.socket_diameter_mm", float(socket_mm)),
        ("socket.window_polar_deg", polar),
        ("socket.window_azimuth_deg", azimuth),
        ("socket.window_half_angle_deg", config.window_half_angle_deg),
        *_reamer(float(reamer_mm)),
        ("reamer_centre_mm", centre),
        ("feed_mm_s", float(pick["feed"])),
        ("cancellous", CANCELLOUS_PRESETS[pick["cancellous"]].model_dump()),
    ]
    if prepared_mm is not None:
        settings.append(("pre_ream_mm", float(prepared_mm)))
    label = (
        f"s{socket_mm:g}_{'n' if prepared_mm is None else f'p{prepared_mm:g}'}_r{reamer_mm:g}_w{polar:g}a{azimuth:g}"
        f"_g{gamma:g}t{theta:g}_c{'x'.join(f'{v:g}' for v in centre)}_v{pick['feed']:g}_{pick['cancellous'][:4]}"
    )
    return CaseSpec(
        inclination_deg=gamma, anteversion_deg=theta, force_n=ReamingCaseConfig.model_fields["force_n"].default,
        frames=config.frames, settings=tuple(settings), label=label, split=split,
    )  # fmt: skip
