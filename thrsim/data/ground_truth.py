"""One ground-truth case: run the explicit reaming solver and write its case file.

The solver (:mod:`thrsim.physics.reaming_case`) returns arrays and a summary; this module turns them
into the HDF5 case file (:mod:`thrsim.data.case_file`), atomically.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from thrsim.config import ReamingCaseConfig
from thrsim.data.case_file import CaseFrames, write_case
from thrsim.data.checkpoint import CHECKPOINT_EVERY_S, Checkpointer, read_checkpoint
from thrsim.geometry.mesh import TetMesh
from thrsim.physics.reaming_case import ENERGY_NAMES, ReamingCase


def run_case(
    case: ReamingCaseConfig,
    out: Path | None,
    progress: Callable[[float, int], None] | None = None,
    mesh: TetMesh | None = None,
    checkpoint: Path | None = None,
    checkpoint_every_s: float = CHECKPOINT_EVERY_S,
) -> dict:
    """Simulate one case, write its case file (when ``out`` is given) and return the JSON summary.

    With ``checkpoint`` (a path, see :mod:`thrsim.data.checkpoint`), the case resumes from the
    checkpoint found there when it is one of this very case, checkpoints every ``checkpoint_every_s``
    seconds, and removes it once the case file is written."""
    simulation = ReamingCase(case, mesh)
    on_frame = None
    if checkpoint is not None:
        snapshot = read_checkpoint(checkpoint, case) if checkpoint.exists() else None
        if snapshot is not None:
            simulation.restore(snapshot)
        on_frame = Checkpointer(checkpoint, case, simulation.snapshot, checkpoint_every_s)
    log, summary = simulation.run(case.frames, progress, on_frame)
    if out is not None:
        records = log.arrays()
        frames = CaseFrames(energy_names=ENERGY_NAMES, **records)
        write_case(
            out, simulation.mesh, frames, simulation.axis,
            inclination_deg=case.inclination_deg, anteversion_deg=case.anteversion_deg, force_n=case.force_n,
            omega_rad_s=case.reamer.omega_rad_s, frame_dt_s=case.frame_dt_s, config=case.model_dump(mode="json"),
            extra_attrs={**summary, "solver": "fem"},
        )  # fmt: skip
        summary["out"] = str(out)
    if checkpoint is not None:
        checkpoint.unlink(missing_ok=True)
    return summary
