"""``thrsim train`` end to end: read a dataset, train, fit the regressor, write the model directory.

The training split trains the networks and the regressor; the validation split drives the
rollouts scored after every epoch; validation and test cases make the regressor's held-out
table. The card records the data (source, per-case digests, split), every setting, the
training history and time, and the code versions.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch

from thrsim.config import LabelConfig
from thrsim.data.pack import ALPHA_LEVELS, is_pack
from thrsim.errors import ThrsimInputError
from thrsim.learn.cases import CaseArrays, feed_range_mm_s, load_cases
from thrsim.learn.graph import StaticGraph, mesh_digest
from thrsim.learn.model_dir import CARD, load_model, read_card, read_mesh, save_advance, save_model
from thrsim.learn.settings import ModelSettings
from thrsim.learn.training import CHECKPOINT, EpochReport, Trainer, train_advance
from thrsim.provenance import package_versions


def data_identity(cases: list[CaseArrays]) -> str:
    digest = hashlib.sha256()
    for case in sorted(cases, key=lambda c: c.case_id):
        digest.update(f"{case.case_id}:{case.split}:{case.digest};".encode())
    return digest.hexdigest()


def train_model(
    data: str | os.PathLike,
    out: str | os.PathLike,
    settings: ModelSettings,
    arch_name: str = "production",
    *,
    overwrite: bool = False,
    init_from: str | os.PathLike | None = None,
    on_start: Callable[[dict], None] | None = None,
    on_epoch: Callable[[EpochReport], None] | None = None,
    on_batch: Callable[[int, int], None] | None = None,
) -> dict:
    """Train into ``out`` (resuming its checkpoint when one of the same run is there); return the card.

    ``init_from``: a trained model directory whose networks (and input normalisers) the run starts
    from instead of fresh weights (fine-tuning, e.g. with other training settings); its card's
    training summary is kept in the new card."""
    out = Path(out)
    if (out / CARD).exists() and not overwrite:
        raise ThrsimInputError(f"{out} already holds a trained model; to replace it, say so (overwrite)", "out", ("overwrite",))
    if out.exists() and not out.is_dir():
        raise ThrsimInputError(f"{out}: exists and is not a directory")
    if not out.parent.is_dir():
        raise ThrsimInputError(f"{out}: parent folder {out.parent} does not exist")
    labels = LabelConfig()
    socket = settings.features.feature_set == "socket"
    mesh, cases = load_cases(data, labels=labels, one_mesh=not socket)
    train = [c for c in cases if c.split == "train"]
    validation = [c for c in cases if c.split == "validation"]
    held_out = [c for c in cases if c.split in ("validation", "test")]
    if not train:
        raise ThrsimInputError(f"{data}: no complete training cases (a dataset directory from `thrsim dataset` is needed)")
    radii = {round(c.teeth_radius_m, 9) for c in cases}
    if len({c.hold for c in train}) != 1:
        raise ThrsimInputError(f"{data}: training cases hold the reamer differently (effective mass, damping); one model learns one hold")
    if len(radii) != 1 and not socket:
        raise ThrsimInputError(f"{data}: cases use different reamers ({sorted(radii)} m teeth radius); one model learns one reamer")
    teeth_radius_m = float(np.median([c.teeth_radius_m for c in train]))
    graph = StaticGraph(mesh)
    init = load_model(init_from, expect_mesh=mesh) if init_from is not None else None
    trainer = Trainer(graph, train, validation, settings, labels.removed_threshold, init)
    checkpoint = out / CHECKPOINT
    out.mkdir(exist_ok=True)
    resumed = trainer.load_checkpoint(checkpoint)
    previous_seconds = sum(h["seconds"] for h in trainer.history)
    if on_start is not None:
        on_start(
            {
                "train_cases": len(train),
                "validation_cases": len(validation),
                "pairs": len(trainer.samples),
                "elements": mesh.n_tets,
                "resumed_at_epoch": trainer.epoch if resumed else None,
            }
        )
    trainer.run(checkpoint, on_epoch, on_batch)
    started = time.perf_counter()
    advance, advance_table = train_advance(train, held_out, settings.train.seed, settings.train.advance_trees, settings.train.advance_kind)
    advance_seconds = time.perf_counter() - started
    history = trainer.history
    card = {
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "thrsim_version": package_versions()["thrsim"],
        "versions": package_versions(),
        "arch": arch_name,
        "settings": settings.model_dump(mode="json"),
        "labels": labels.model_dump(mode="json"),
        "reamer": {
            "teeth_radius_m": teeth_radius_m,
            "omega_rad_s": float(np.median([c.omega_rad_s for c in cases])),
            "sizes_mm": sorted({round(2e3 * c.teeth_radius_m, 3) for c in train}),
            "hold": train[0].hold.model_dump(mode="json"),
        },
        "data": {
            "source": str(data),  # as given: a shipped card names no machine's folders
            "form": f"learning pack (α in levels of 1/{ALPHA_LEVELS})" if is_pack(data) else "case files",
            "digest": data_identity(cases),
            "solver_versions": sorted({c.solver_version for c in cases}),
            "split": {name: sorted(c.case_id for c in cases if c.split == name) for name in ("train", "validation", "test")},
            "force_range_n": [min(c.recorded_push_n() for c in train), max(c.recorded_push_n() for c in train)],
            "inclination_range_deg": [min(c.inclination_deg for c in train), max(c.inclination_deg for c in train)],
            "anteversion_range_deg": anteversion_range_deg(train),
            "axis_offset_range_mm": [min(c.axis_offset_mm() for c in train), max(c.axis_offset_mm() for c in train)],
            "feed_range_mm_s": feed_range_mm_s(train),
            "frame_dt_s": float(np.median([c.frame_dt_s for c in train])),
            "frame_pairs": int(len(trainer.samples)),
            "reaction_cases": sorted(trainer.reaction_case_ids) if settings.arch.reaction_head else [],
            "law_contact_mm2": trainer.law_contact_range_mm2() if settings.arch.reaction_head else None,
        },
        "training": {
            "epochs": trainer.epoch,
            "network_seconds": sum(h["seconds"] for h in history),
            "advance_seconds": advance_seconds,
            "resumed": resumed,
            "seconds_before_resume": previous_seconds if resumed else 0.0,
            "threads": torch.get_num_threads(),
            "device": "cpu",
            "history": history,
            "init_from": None
            if init is None
            else {
                "source": str(init_from),
                "weights_digest": trainer.init_digest,
                "data_digest": init.card["data"]["digest"],
                "settings": init.card["settings"],
                "training": {k: v for k, v in init.card["training"].items() if k != "history"},
            },
        },
        "metrics": {
            "final_gn_loss": history[-1]["gn_loss"] if history else None,
            "final_mlp_loss": history[-1]["mlp_loss"] if history else None,
            "validation_f1": history[-1]["validation_f1"] if history else None,
        },
        "advance": advance_table,
        "parameters": {"gn": sum(p.numel() for p in trainer.gn.parameters()), "mlp": sum(p.numel() for p in trainer.mlp.parameters())},
    }
    save_model(out, card, trainer.gn, trainer.mlp, advance, mesh)
    shutil.rmtree(checkpoint, ignore_errors=True)
    return card


def anteversion_range_deg(train: list[CaseArrays]) -> list[float]:
    """The lowest and highest tilt direction θ of the training cases, as their regressor reads it."""
    return [min(c.anteversion_deg for c in train), max(c.anteversion_deg for c in train)]


def refit_advance(data: str | os.PathLike, out: str | os.PathLike, kind: str | None = None) -> dict:
    """Refit the reamer regressor of the trained model in ``out`` on the data it was trained on,
    keeping its networks (minutes of training) untouched, as its settings' ``advance_kind`` or
    ``kind`` (which the card's settings then record); return the updated card."""
    out = Path(out)
    card = read_card(out)
    mesh = read_mesh(out)
    labels = LabelConfig(**card["labels"])
    data_mesh, cases = load_cases(data, labels=labels)
    if mesh_digest(data_mesh) != mesh_digest(mesh):
        raise ThrsimInputError(f"{data}: another mesh than the model in {out}")
    if data_identity(cases) != card["data"]["digest"]:
        raise ThrsimInputError(f"{data}: not the data the model in {out} was trained on (its card names {card['data']['source']})")
    train = [c for c in cases if c.split == "train"]
    held_out = [c for c in cases if c.split in ("validation", "test")]
    if kind is not None:
        card["settings"]["train"]["advance_kind"] = kind
    settings = ModelSettings.model_validate(card["settings"])
    started = time.perf_counter()
    advance, advance_table = train_advance(train, held_out, settings.train.seed, settings.train.advance_trees, settings.train.advance_kind)
    card = {
        **card,
        "data": {**card["data"], "anteversion_range_deg": anteversion_range_deg(train)},
        "settings": settings.model_dump(mode="json"),
        "advance": advance_table,
        "advance_refit_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "thrsim_version": package_versions()["thrsim"],
        "versions": package_versions(),
        "training": {**card["training"], "advance_seconds": time.perf_counter() - started},
    }
    save_advance(out, card, advance)
    return card
