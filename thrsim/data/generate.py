"""Generate a sweep of ground-truth cases into a dataset directory, resumably.

The directory holds ``manifest.json`` (every case's parameters, split, solver, checksums and how it
ended; written atomically by the coordinating process after every case), ``cases/<case_id>.h5``
and a ``.lock`` held while a run goes on (layout: the docs' Data formats page). A worker solves
into a temporary ``.part`` file, validates it and renames it, so a file under its final name is
complete. Rerunning the same command skips cases that match the manifest, adopts complete files
it missed and redoes the rest: killing any process at any moment loses at most the cases in
flight. Ctrl-C, SIGTERM and a full disk stop the sweep at once, with every finished case in the
manifest. A directory made by another configuration is refused rather than mixed.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import importlib
import inspect
import json
import os
import socket
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from thrsim import __version__
from thrsim.atomic import atomic_path, check_folder_creatable, fsync_folder
from thrsim.config import ReamingCaseConfig
from thrsim.data.case_file import CaseReader, data_digest, file_sha256, file_solution_hash, solution_hash, validate_case
from thrsim.data.checkpoint import checkpoint_path, checkpointed_frames
from thrsim.data.executor import Executor, cap_numerical_threads, is_worker_lost, make_executor
from thrsim.data.sweep import DEFAULT_SPLIT, CaseSpec, SocketSplitRule, SplitRule, SweepPlan, coverage_order
from thrsim.errors import ThrsimInputError, ThrsimOutputError
from thrsim.provenance import config_hash, json_default

MANIFEST = "manifest.json"
MANIFEST_FORMAT = "thrsim-dataset"
MANIFEST_VERSION = 1
CASES_DIR = "cases"
LOCK = ".lock"
MAX_ATTEMPTS = 3
SOLVERS = {
    "fem": "thrsim.data.ground_truth:run_case",
    "synthetic": "thrsim.data.synthetic:synthetic_run_case",
}
# the per-case axes; everything else of ReamingCaseConfig is the dataset's fixed template
_AXES = ("inclination_deg", "anteversion_deg", "force_n")


def resolve_solver(solver: str | Callable) -> Callable:
    """'fem' (the explicit solver), 'synthetic' (the test stand-in), a callable (Python callers),
    or 'thrsim.module:function'; a module outside thrsim is refused before it is imported."""
    if callable(solver):
        return solver
    ref = SOLVERS.get(solver, solver)
    module_name, _, attr = ref.partition(":")
    if not module_name or not attr:
        raise ThrsimInputError(f"unknown solver {solver!r}: use {', '.join(SOLVERS)}")
    if module_name.split(".")[0] != "thrsim":
        raise ThrsimInputError(f"solver {solver!r}: only thrsim's own solvers are run by name ({', '.join(SOLVERS)})")
    try:
        module = importlib.import_module(module_name)
        return getattr(module, attr)
    except (ImportError, AttributeError) as error:
        raise ThrsimInputError(f"solver {solver!r} is not available ({error})") from None


def solver_name(solver: str | Callable) -> str:
    if callable(solver):
        return f"{solver.__module__}:{solver.__qualname__}"
    return solver


def template_of(frames: int, overrides: dict | None = None) -> dict:
    """The dataset's fixed case configuration: a ReamingCaseConfig dump without the sweep axes."""
    base = ReamingCaseConfig(inclination_deg=0.0, anteversion_deg=0.0, frames=frames, **(overrides or {}))
    data = base.model_dump(mode="json")
    for key in _AXES:
        data.pop(key)
    return data


def dataset_identity(template: dict, solver: str, element_sizes: tuple) -> dict:
    """What must match for two runs to share a directory."""
    ident = {"template": template, "solver": solver, "thrsim_version": __version__}
    if any(h is not None for h in element_sizes):
        ident["template"] = {**template, "bone": {k: v for k, v in template["bone"].items() if k != "element_size_mm"}}
    return ident


# ---------------------------------------------------------------- the task run on a worker


def run_one_case(params: dict, template: dict, cases_dir: str, solver: str | Callable, threads: int | None = None) -> dict:
    """Run one case on a worker, verify it, rename it into place; return what the manifest records."""
    if threads:
        cap_numerical_threads(threads)
    spec = CaseSpec(**{**params, "aliases": tuple(params.get("aliases", ()))})
    config = spec.case_config(template)
    folder = Path(cases_dir)
    final = folder / f"{spec.case_id}.h5"
    part = folder / f"{spec.case_id}.h5.{uuid.uuid4().hex[:12]}.part"
    solve = resolve_solver(solver)
    started = time.perf_counter()
    try:
        if "checkpoint" in inspect.signature(solve).parameters:  # a long case resumes after a lost worker
            summary = solve(config, part, checkpoint=checkpoint_path(final)) or {}
        else:
            summary = solve(config, part) or {}
        wall = time.perf_counter() - started
        check = validate_case(part)
        _check_matches(check, spec, part, template)
        sha = file_sha256(part)
        digest = data_digest(part)
        os.replace(part, final)
        fsync_folder(folder)
    except ThrsimOutputError as error:  # the user knows the case file, not its part name
        raise ThrsimOutputError(error.errno, error.strerror, str(final)) from None
    finally:
        if part.exists():
            part.unlink()
    return {
        "case_id": spec.case_id,
        "wall_s": wall,
        **_file_record(check, sha, digest),
        "solver_summary": json.loads(json.dumps(summary, default=json_default)),
        "worker": f"{socket.gethostname()}:{os.getpid()}",
    }


def _file_record(check: dict, sha: str, digest: str) -> dict:
    """What the manifest keeps of a validated case file."""
    return {
        "frames": check["frames"],
        "elements": check["elements"],
        "removed": check["removed"],
        "removed_per_frame": check["removed_per_frame"],
        "config_hash": check.get("config_hash"),
        "sha256": sha,
        "data_digest": digest,
    }


def _check_matches(check: dict, spec: CaseSpec, path: Path, template: dict) -> None:
    """Refuse a case file that is not ``spec``'s case: its axes, its configuration (threads aside) or too many frames."""
    if check.get("solution_hash") != solution_hash(spec.case_config(template).model_dump(mode="json")):
        raise ThrsimInputError(f"{path}: solved with another configuration than case {spec.case_id}")
    for key, want in (("inclination_deg", spec.inclination_deg), ("anteversion_deg", spec.anteversion_deg), ("force_n", spec.force_n)):
        got = check.get(key)
        if got is None or abs(float(got) - want) > 1e-6:
            raise ThrsimInputError(f"{path}: {key} is {got}, expected {want:g} for case {spec.case_id}")
    if check["frames"] > spec.frames + 1:  # frame 0 (intact, before contact) plus at most the frames asked for
        raise ThrsimInputError(f"{path}: {check['frames']} frames, more than the {spec.frames} asked for (+ frame 0)")


# ---------------------------------------------------------------- manifest


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


class _ManifestPart(BaseModel):
    """A part of the manifest that the commands read: its fields typed, any others kept."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


class ManifestEntry(_ManifestPart):
    file: str = Field(pattern=rf"^{CASES_DIR}/[^/\\]+\.h5$", description="the case file, inside the dataset's cases folder")
    status: str
    split: str | None = None
    params: dict = {}
    data_digest: str | None = None
    sha256: str | None = None
    attempts: int = Field(0, ge=0)
    frames: int = Field(0, ge=0)
    wall_s: float | None = Field(None, ge=0, description="None for a file adopted after a crash")


class Manifest(_ManifestPart):
    """The manifest's checked shape (:func:`read_manifest`): a file of other types is refused with one line."""

    identity: dict
    identity_hash: str
    cases: dict[str, ManifestEntry]
    split_rule: dict | None = None
    runs: list[dict] = []


def read_manifest(root: Path) -> dict | None:
    path = root / MANIFEST
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError) as error:
        raise ThrsimInputError(f"{path}: unreadable dataset manifest ({' '.join(str(error).split()) or 'nested too deeply'})") from None
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        raise ThrsimInputError(f"{path}: not a thrsim dataset manifest")
    try:
        Manifest.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        raise ThrsimInputError(f"{path}: malformed dataset manifest: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None
    return data


def write_manifest(root: Path, manifest: dict) -> None:
    manifest["updated"] = _now()
    with atomic_path(root / MANIFEST) as tmp:
        with open(tmp, "w") as handle:
            json.dump(manifest, handle, indent=1, sort_keys=False)
            handle.flush()
            os.fsync(handle.fileno())
    fsync_folder(root)


def _differences(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _differences(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [f"{prefix[:-1]} ({a!r} there, {b!r} now)"]


def check_directory(root: Path, identity: dict, case_files: frozenset[str] = frozenset()) -> dict | None:
    """Refuse a directory that is not ours or was made by another configuration; return its manifest.
    A new dataset's cases folder may hold files named as ``case_files`` (the plan's cases solved
    elsewhere, e.g. by ``thrsim fem``): the run adopts each that was solved as its case, redoes the rest."""
    if root.exists() and not root.is_dir():
        raise ThrsimInputError(f"{root}: exists and is not a directory")
    manifest = read_manifest(root) if root.exists() else None
    if manifest is None:
        if root.exists() and any(p.name not in (LOCK, CASES_DIR) for p in root.iterdir()):
            raise ThrsimInputError(f"{root}: not empty and not a thrsim dataset (no {MANIFEST}); refusing to write into it")
        if (root / CASES_DIR).exists() and any(path.name not in case_files for path in (root / CASES_DIR).glob("*.h5")):
            raise ThrsimInputError(f"{root}: holds case files that are not the plan's cases and no {MANIFEST}; refusing to mix")
        return None
    if manifest.get("identity_hash") != config_hash(identity):
        diffs = _differences(manifest.get("identity", {}), identity)
        shown = "; ".join(diffs[:3]) + (f"; and {len(diffs) - 3} more" if len(diffs) > 3 else "")
        raise ThrsimInputError(f"{root} was made by a different configuration ({shown or 'identity differs'}); use another", "out")
    return manifest


@contextlib.contextmanager
def _locked(root: Path) -> Iterator[None]:
    handle = open(root / LOCK, "a+")
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            if error.errno in (errno.EAGAIN, errno.EACCES):
                raise ThrsimInputError(f"{root}: another thrsim dataset run is writing here") from None
            raise
        yield
    finally:
        handle.close()


# ---------------------------------------------------------------- the sweep


@dataclass
class SweepEvent:
    """What a progress display needs after each finished case."""

    case_id: str
    status: str  # complete, skipped, adopted, failed, retry
    done: int
    total: int
    frames: int = 0
    wall_s: float = 0.0
    message: str = ""
    removed: int = 0
    end_reason: str = ""


@dataclass
class SweepResult:
    root: Path
    total: int
    complete: int
    skipped: int
    adopted: int
    failed: dict[str, str] = field(default_factory=dict)
    frames_generated: int = 0
    wall_s: float = 0.0
    executor: str = ""
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        return {
            "out": str(self.root),
            "cases": self.total,
            "generated": self.complete,
            "skipped": self.skipped,
            "adopted": self.adopted,
            "failed": len(self.failed),
            "failures": self.failed,
            "frames_generated": self.frames_generated,
            "wall_s": self.wall_s,
            "frames_per_second": self.frames_generated / self.wall_s if self.wall_s > 0 else 0.0,
            "executor": self.executor,
            "notes": self.notes,
        }


def _clean_stale(cases: Path) -> None:
    for path in list(cases.glob("*.part")) + list(cases.glob(".*.tmp")):
        with contextlib.suppress(OSError):
            path.unlink()


def _entry(spec: CaseSpec, split: SplitRule | SocketSplitRule, solver: str) -> dict:
    return {
        "params": spec.params(),
        "split": split.of(spec),
        "file": f"{CASES_DIR}/{spec.case_id}.h5",
        "solver": solver,
        "solver_version": __version__,
        "status": "pending",
        "attempts": 0,
    }


def _existing_complete(root: Path, spec: CaseSpec, entry: dict | None, template: dict) -> tuple[str, dict] | None:
    """('skipped', entry) when the manifest's checksum matches, ('adopted', fields) when a valid
    file is there that the manifest missed, None when the case must run; a file solved with another
    configuration than ``spec``'s (a changed plan) is neither."""
    path = root / CASES_DIR / f"{spec.case_id}.h5"
    if not path.exists():
        return None
    sha = file_sha256(path)
    if entry and entry.get("status") == "complete" and entry.get("sha256") == sha:
        same = file_solution_hash(path) == solution_hash(spec.case_config(template).model_dump(mode="json"))
        return ("skipped", entry) if same else None
    try:
        check = validate_case(path)
        _check_matches(check, spec, path, template)
    except ThrsimInputError:
        return None
    with CaseReader(path) as reader:  # what the solver said of the case, as its file keeps it
        summary = {key: value for key, value in reader.attrs.items() if key not in ("config", "versions", "format")}
    return "adopted", {
        **_file_record(check, sha, data_digest(path)),
        "wall_s": None,
        "solver_summary": json.loads(json.dumps(summary, default=json_default)),
    }


@dataclass(frozen=True)
class SweepTarget:
    """What a sweep into a folder is, checked before anything runs: see :func:`check_sweep_target`."""

    template: dict
    solver: str
    identity: dict
    manifest: dict | None  # the folder's manifest, None for a new dataset


def check_sweep_target(
    root: Path, plan: SweepPlan, *, solver: str | Callable = "fem", template_overrides: dict | None = None
) -> SweepTarget:
    """Every refusal a sweep can meet before it runs, without touching ``root``.

    The plan asks one frame count (or names the dataset's, its long cases asking more), the solver
    is known, ``root`` is a dataset of this very configuration (or empty, or absent) and can be
    created. ``--dry-run`` calls this too, so what it approves, the run accepts.
    """
    frames = {c.frames for c in plan.cases}
    if plan.frames is None and len(frames) != 1:
        raise ThrsimInputError("every case of one dataset must ask for the same number of frames")
    template = template_of(plan.frames or frames.pop(), template_overrides)
    name = solver_name(solver)
    identity = dataset_identity(template, name, tuple(c.element_size_mm for c in plan.cases))
    manifest = check_directory(root, identity, frozenset(f"{case.case_id}.h5" for case in plan.cases))
    check_folder_creatable(root, "dataset folder")
    if not callable(solver):
        resolve_solver(solver)  # an unknown solver is an input error, found before any work
    return SweepTarget(template, name, identity, manifest)


def without_packed(plan: SweepPlan, pack: str | os.PathLike, identity: dict) -> SweepPlan:
    """``plan`` less the cases a learning pack of this same dataset holds: a plan solved across
    machines or sessions (pack what is done, solve the rest anywhere, pack them into that pack)."""
    from thrsim.data.pack import packed_case_ids

    identity_hash, held = packed_case_ids(pack)
    if identity_hash != config_hash(identity):
        raise ThrsimInputError(
            f"{pack}: a pack of another dataset (solver, thrsim version or case settings differ from this sweep's)", "except_packed"
        )
    kept = [case for case in plan.cases if case.case_id not in held]
    return replace(plan, cases=kept, notes=[*plan.notes, f"{len(plan.cases) - len(kept)} case(s) of the plan are in {pack}: not run"])


def run_sweep(
    root: str | os.PathLike,
    plan: SweepPlan,
    *,
    solver: str | Callable = "fem",
    workers: int = 1,
    scheduler: str | None = None,
    executor: Executor | None = None,
    template_overrides: dict | None = None,
    split: SplitRule | SocketSplitRule = DEFAULT_SPLIT,
    connect_timeout_s: float = 5.0,
    threads: int | None = None,
    on_event: Callable[[SweepEvent], None] | None = None,
    on_start: Callable[[int, int, str], None] | None = None,
) -> SweepResult:
    """Run every case of ``plan`` not already complete in ``root``; return the tally.

    Input problems (a different configuration in ``root``, an unreachable scheduler) raise
    :class:`ThrsimInputError` before anything in ``root`` is touched. The steps: check the
    target (:func:`check_sweep_target`), take the folder's lock, take stock of the cases already
    there (:meth:`_Sweep.take_stock`), run the rest with retries (:meth:`_Sweep.run`).
    """
    root = Path(root)
    target = check_sweep_target(root, plan, solver=solver, template_overrides=template_overrides)
    own_executor = executor is None
    if executor is None:
        executor = make_executor(workers=workers, scheduler=scheduler, connect_timeout_s=connect_timeout_s, threads=threads)
    if threads is None:  # local: the cores shared among the workers; Dask: 1 (scale with worker processes)
        threads = getattr(executor, "threads_per_worker", 1)
    started = time.perf_counter()
    try:
        root.mkdir(parents=True, exist_ok=True)
        with _locked(root):
            (root / CASES_DIR).mkdir(exist_ok=True)
            manifest = _open_manifest(read_manifest(root) or target.manifest, target.identity, split)
            manifest.setdefault("runs", []).append(
                {"started": _now(), "executor": executor.description, "threads_per_case": threads, "cases": len(plan.cases)}
            )
            _clean_stale(root / CASES_DIR)
            sweep = _Sweep(
                root,
                manifest,
                SweepResult(
                    root=root,
                    total=len(plan.cases),
                    complete=0,
                    skipped=0,
                    adopted=0,
                    executor=executor.description,
                    notes=list(plan.notes),
                ),
                on_event,
            )
            todo = sweep.take_stock(coverage_order(plan.cases, plan.main_forces_n), split, target.solver)
            if on_start:
                on_start(sweep.done, sweep.result.total, executor.description)
            sweep.run(executor, todo, target.template, solver, threads)
            sweep.result.wall_s = time.perf_counter() - started
            manifest["runs"][-1].update(
                finished=_now(), wall_s=sweep.result.wall_s, generated=sweep.result.complete, failed=len(sweep.result.failed)
            )
            write_manifest(root, manifest)
            _clean_stale(root / CASES_DIR)
            return sweep.result
    finally:
        if own_executor:
            executor.close(cancel=True)


def _open_manifest(manifest: dict | None, identity: dict, split: SplitRule | SocketSplitRule) -> dict:
    """The folder's manifest, or a new one for this identity; the split rule is this run's."""
    if manifest is None:
        manifest = {
            "format": MANIFEST_FORMAT,
            "version": MANIFEST_VERSION,
            "created": _now(),
            "identity": identity,
            "identity_hash": config_hash(identity),
            "cases": {},
        }
    manifest["split_rule"] = split.as_dict()
    return manifest


class _Sweep:
    """One run's bookkeeping: the manifest entries, the tally, the progress events."""

    def __init__(self, root: Path, manifest: dict, result: SweepResult, on_event: Callable[[SweepEvent], None] | None):
        self.root = root
        self.manifest = manifest
        self.result = result
        self.on_event = on_event
        self.done = 0

    def emit(self, case_id: str, status: str, **fields: Any) -> None:
        if self.on_event:
            self.on_event(SweepEvent(case_id, status, self.done, self.result.total, **fields))

    def save(self) -> None:
        write_manifest(self.root, self.manifest)

    # ---- adoption: what is already on disk

    def take_stock(self, specs: list[CaseSpec], split: SplitRule | SocketSplitRule, solver: str) -> list[CaseSpec]:
        """Skip cases whose file matches the manifest, adopt valid files it missed; return the rest."""
        cases = self.manifest["cases"]
        todo: list[CaseSpec] = []
        for spec in specs:
            old = cases.get(spec.case_id)
            entry = {**(old or {}), **_entry(spec, split, solver), "attempts": (old or {}).get("attempts", 0)}
            found = _existing_complete(self.root, spec, old, self.manifest["identity"]["template"])
            if found is None:
                entry.pop("in_progress", None)
                checkpoint = checkpoint_path(self.root / CASES_DIR / f"{spec.case_id}.h5")
                frames_done = checkpointed_frames(checkpoint) if checkpoint.exists() else None
                if frames_done is not None:  # a case interrupted after a checkpoint: it resumes there
                    entry["in_progress"] = {"checkpoint": f"{CASES_DIR}/{checkpoint.name}", "frames_done": frames_done}
                cases[spec.case_id] = {**entry, "status": "pending"}
                todo.append(spec)
                continue
            kind, fields = found
            if kind == "skipped":
                entry = {**old, **{k: v for k, v in entry.items() if k in ("params", "split", "file")}}
                self.result.skipped += 1
            else:
                entry.update(fields, status="complete", adopted=True, finished=_now())
                self.result.adopted += 1
            cases[spec.case_id] = entry
            self.done += 1
            self.emit(spec.case_id, kind, frames=entry.get("frames", 0))
        self.save()
        return todo

    # ---- scheduling and retries

    def run(self, executor: Executor, todo: list[CaseSpec], template: dict, solver: str | Callable, threads: int | None) -> None:
        """Submit every case; a case whose worker died is resubmitted (at most MAX_ATTEMPTS runs)."""
        attempts: dict[str, int] = {}
        cases_dir = str(self.root / CASES_DIR)
        queue = list(todo)
        while queue:
            futures = {}
            for spec in queue:
                attempts[spec.case_id] = attempts.get(spec.case_id, 0) + 1
                entry = self.manifest["cases"][spec.case_id]
                entry["attempts"] = entry.get("attempts", 0) + 1
                futures[executor.submit(run_one_case, spec.params(), template, cases_dir, solver, threads, key=spec.case_id)] = spec
            self.save()
            retry: list[CaseSpec] = []
            broken = False
            try:
                for future in executor.as_completed(list(futures)):
                    spec = futures[future]
                    try:
                        fields = future.result()
                    except ThrsimOutputError:
                        raise  # a full disk fails every case alike: stop the sweep
                    except Exception as error:  # noqa: BLE001 - every failure is recorded per case
                        broken = broken or is_worker_lost(error)
                        if is_worker_lost(error) and attempts[spec.case_id] < MAX_ATTEMPTS:
                            retry.append(spec)
                            self.emit(spec.case_id, "retry", message="worker lost")
                        else:
                            self.failed(spec, error, attempts[spec.case_id])
                        continue
                    self.completed(spec, fields)
            except BaseException as stop:  # Ctrl-C, SIGTERM, a full disk
                self.stop(executor, futures, stop)
                raise
            if broken:
                executor.restart()
            queue = retry

    def stop(self, executor: Executor, futures: dict[Any, CaseSpec], reason: BaseException) -> None:
        """End the sweep now: record the results already in, end the workers, adopt the case files
        they renamed into place before they ended, and write the manifest (at best: a full disk
        may refuse it; the next run adopts those files then)."""
        pending = {spec.case_id: spec for spec in futures.values() if self.manifest["cases"][spec.case_id].get("status") == "pending"}
        for future, spec in futures.items():
            if spec.case_id in pending and future.done() and not future.cancelled():
                with contextlib.suppress(Exception):  # a failed case stays pending: the next run redoes it
                    self.completed(spec, future.result(), save=False)
                    del pending[spec.case_id]
        executor.stop()
        for case_id, spec in pending.items():
            found = _existing_complete(self.root, spec, None, self.manifest["identity"]["template"])
            if found is not None:
                self.manifest["cases"][case_id].update(found[1], status="complete", adopted=True, finished=_now())
                self.result.adopted += 1
        _clean_stale(self.root / CASES_DIR)
        self.manifest["runs"][-1].update(stopped=_now(), stop_reason=str(reason) or type(reason).__name__)
        with contextlib.suppress(OSError):
            self.save()

    # ---- progress: the manifest after every case, and an event

    def failed(self, spec: CaseSpec, error: BaseException, attempts: int) -> None:
        if is_worker_lost(error):
            message = f"worker died {attempts} times running this case"
        else:
            text = str(error).strip()
            message = f"{type(error).__name__}: {text.splitlines()[0] if text else ''}"
        self.manifest["cases"][spec.case_id].update(status="failed", error=message, finished=_now())
        self.result.failed[spec.case_id] = message
        self.done += 1
        self.save()
        self.emit(spec.case_id, "failed", message=message)

    def completed(self, spec: CaseSpec, fields: dict, save: bool = True) -> None:
        fields = {k: v for k, v in fields.items() if k != "case_id"}
        entry = self.manifest["cases"][spec.case_id]
        entry.update(fields, status="complete", finished=_now())
        entry.pop("error", None)
        entry.pop("adopted", None)
        entry.pop("in_progress", None)
        self.result.complete += 1
        self.result.frames_generated += int(fields["frames"])
        self.done += 1
        if save:
            self.save()
        self.emit(
            spec.case_id, "complete", frames=int(fields["frames"]), wall_s=float(fields["wall_s"]), removed=int(fields["removed"]),
            end_reason=str((fields.get("solver_summary") or {}).get("end_reason", "")),
        )  # fmt: skip


def load_dataset(root: str | os.PathLike, split: str | None = None, complete_only: bool = True) -> list[dict]:
    """The manifest's case entries (with absolute ``path``), optionally one split only."""
    root = Path(root)
    manifest = read_manifest(root)
    if manifest is None:
        raise ThrsimInputError(f"{root}: not a thrsim dataset (no {MANIFEST})")
    out = []
    for case_id, entry in sorted(manifest["cases"].items()):
        if complete_only and entry.get("status") != "complete":
            continue
        if split is not None and entry.get("split") != split:
            continue
        out.append({**entry, "case_id": case_id, "path": str(root / entry["file"])})
    return out
