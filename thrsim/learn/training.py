"""Training: the Graph Network and the MLP baseline on one-step pairs, then the advance regressor.

Each sample is a frame pair (t, t + 1) of a training case, cut to the region near the reamer at
t + 1 plus its halo (the subgraph the simulator evaluates), with Gaussian noise on the input α
(and D) of active elements and on the reamer centre (MeshGraphNets-style, for stable rollouts).
With pushforward (``TrainSettings.pushforward_steps``) a share of the inputs are the network's
own tool-forced rollout from an earlier ground-truth frame, the targets still the solver's, so it
learns from the states it drifts into. Both networks see the same batches; the loss is eq. 49's
cross-entropy on α(t+1), plus the removal head's and D(t+1)'s. Every epoch draws its order and
noise from ``(seed, epoch)`` alone, so a run resumed from its checkpoint gives the same weights
as one never interrupted; tool-forced validation rollouts score F1 after each epoch.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file as load_tensors
from safetensors.torch import save as tensor_bytes

from thrsim.atomic import atomic_path
from thrsim.errors import ThrsimInputError
from thrsim.learn.advance import LOWEST_CV, case_samples, fit_advance
from thrsim.learn.cases import CaseArrays, case_graphs, require_damage
from thrsim.learn.features import GraphBatch, ReamerState, batch, frame_arrays, law_contact_mm2, law_weights, select_subgraph
from thrsim.learn.graph import StaticGraph
from thrsim.learn.learned_simulator import STALL_FEED_M_S, LearnedSimulator
from thrsim.learn.metrics import Counts
from thrsim.learn.model_dir import LoadedModel
from thrsim.learn.rollout import BoneState, LearnedStep, rollout
from thrsim.learn.settings import ModelSettings
from thrsim.provenance import config_hash

CHECKPOINT = "checkpoint"


@dataclass
class EpochReport:
    epoch: int
    epochs: int
    gn_loss: float
    mlp_loss: float
    validation_f1: float | None
    seconds: float


class Trainer:
    """Holds the data, both networks and their optimisers; ``run`` trains epoch by epoch."""

    def __init__(
        self,
        graph: StaticGraph,
        train: list[CaseArrays],
        validation: list[CaseArrays],
        settings: ModelSettings,
        threshold: float,
        init: LoadedModel | None = None,
    ):
        if not train:
            raise ThrsimInputError("no training cases")
        self.graph, self.train_cases, self.validation = graph, train, validation
        self.settings, self.threshold = settings, threshold
        self.graphs = case_graphs(graph, [*train, *validation], any_mesh=settings.features.feature_set == "socket")
        if settings.arch.reaction_head:
            unrecorded = [case.case_id for case in train if case.reaction_n is None or case.motor_torque_n_m is None]
            if unrecorded:
                raise ThrsimInputError(
                    f"{len(unrecorded)} case(s) record no reaction or torque (e.g. {unrecorded[0]}), which the reaction head learns"
                )
        if settings.features.damage:
            require_damage([*train, *validation], 'regenerate the data or train with the settings {"features": {"damage": false}}')
        # the reaction law learns where the push drove the reamer (its feed is the bone's answer to a push);
        # a rig's set feed shows the force a feed takes, not the push a feed needs (see the docs' benchmarks)
        pushed = {case.case_id for case in train if case.set_feed_mm_s is None}
        if settings.train.law_from == "whole_socket":
            pushed = {case.case_id for case in train if case.case_id in pushed and not case.is_window()}
            if settings.arch.reaction_head and not pushed:
                raise ThrsimInputError("the law learns from pushed whole sockets (train.law_from) and the training split has none")
        self.reaction_case_ids = pushed or {case.case_id for case in train}
        # the push each law case was reamed with, which the balanced feed of the law's loss meets
        self.pushes = {case.case_id: case.recorded_push_n() for case in train if case.case_id in self.reaction_case_ids}
        self.samples = np.array([(c, t) for c, case in enumerate(train) for t in range(case.frames - 1)], dtype=np.int64)
        if len(self.samples) == 0:
            raise ThrsimInputError("the training cases hold no frame pairs")
        torch.manual_seed(settings.train.seed)
        self.gn = LearnedSimulator(settings, "gn", threshold)
        self.mlp = LearnedSimulator(settings, "mlp", threshold)
        self.optimisers = {
            "gn": torch.optim.Adam(self.gn.parameters(), lr=settings.train.learning_rate),
            "mlp": torch.optim.Adam(self.mlp.parameters(), lr=settings.train.learning_rate),
        }
        self.epoch = 0
        self.history: list[dict] = []
        self.init_digest: str | None = None
        if init is None:
            self._fit_normalisers()
        else:
            self._start_from(init)

    def _start_from(self, init: LoadedModel) -> None:
        """Warm start: both networks and their normalisers from a trained model of the same architecture
        (its reaction prior may differ: the network is the same, the law's weights are not)."""
        same_network = init.settings.arch.model_copy(update={"reaction_prior": self.settings.arch.reaction_prior}) == self.settings.arch
        if not same_network or init.settings.features.network_inputs() != self.settings.features.network_inputs():
            raise ThrsimInputError(
                f"{init.path}: its architecture or input features differ from this run's; a warm start needs the same network "
                "(only the region a step updates and the reaction law's prior may differ)"
            )
        if init.graph.digest != self.graph.digest:
            raise ThrsimInputError(f"{init.path}: belongs to another mesh than the data")
        self.gn.load_state_dict(init.gn.state_dict())
        self.mlp.load_state_dict(init.mlp.state_dict())
        digest = hashlib.sha256()
        for name, tensor in sorted({**init.gn.state_dict(), **{f"mlp.{k}": v for k, v in init.mlp.state_dict().items()}}.items()):
            digest.update(name.encode())
            digest.update(tensor.detach().contiguous().numpy().tobytes())
        self.init_digest = digest.hexdigest()

    def law_contact_range_mm2(self) -> list[float] | None:
        """The smallest and largest contact (:func:`~thrsim.learn.features.law_contact_mm2`) of the frames
        the reaction law learns from (None without them): beyond it a step's law is an extrapolation."""
        contacts = []
        for case_index, t in self.samples:
            case = self.train_cases[case_index]
            if case.case_id not in self.reaction_case_ids or math.isnan(next_reaction(case, int(t) + 1, self.threshold)[0]):
                continue
            graph = self.graphs[case.case_id]
            sub = select_subgraph(
                graph, self.settings.features, case.alpha[t] >= self.threshold, case.positions[t + 1], case.teeth_radius_m
            )
            if sub.n_region:
                contacts.append(law_contact_mm2(graph, sub))
        return [min(contacts), max(contacts)] if contacts else None

    def _step(self, model: LearnedSimulator, case: CaseArrays) -> LearnedStep:
        """The learned step on ``case``'s bone, with its reamer."""
        return LearnedStep(model, self.graphs[case.case_id], self.settings.features, case.teeth_radius_m, case.element_cutting_energy_j_m3)

    def _pushed_steps(self, t: int, rng: np.random.Generator | None) -> int:
        """How many of the network's own steps lead to the input at t (0: the ground truth)."""
        train = self.settings.train
        if rng is None or train.pushforward_steps == 0 or t == 0 or self.epoch < train.pushforward_from_epoch:
            return 0
        if rng.random() >= train.pushforward_fraction:
            return 0
        return int(rng.integers(1, min(t, train.pushforward_steps) + 1))

    def _pushed_state(self, case: CaseArrays, t: int, steps: int) -> BoneState:
        """The bone at t from the Graph Network's tool-forced rollout of ``steps`` frames from the ground truth."""
        was_training = self.gn.training
        step = self._step(self.gn, case)
        state = BoneState.start(case.alpha[t - steps], None if case.damage is None else case.damage[t - steps])
        for frame in range(t - steps + 1, t + 1):
            moved = float((case.positions[frame] - case.positions[frame - 1]) @ case.axis)
            state = step(state, case.positions[frame], case.axis, case.force_n, moved, case.omega_rad_s)
        self.gn.train(was_training)
        return state

    def _noisy(self, values: np.ndarray, active: np.ndarray, low: float, rng: np.random.Generator | None, sigma: float) -> np.ndarray:
        """``values`` with Gaussian noise (σ ``sigma``) on active elements, clipped to [low, 1]."""
        if rng is None or sigma == 0:
            return values
        noisy = np.clip(values + rng.normal(0.0, sigma, len(values)).astype(np.float32), low, 1.0)
        return np.where(active, noisy, values).astype(np.float32)

    @staticmethod
    def _reamer(case: CaseArrays, t: int, centre: np.ndarray) -> ReamerState:
        """The reamer at frame pair t → t + 1: its head at ``centre`` after the recorded advance."""
        advance = float((case.positions[t + 1] - case.positions[t]) @ case.axis)
        return ReamerState(centre, case.axis, case.force_n, advance, case.omega_rad_s, case.teeth_radius_m)

    def _law_weights(self, case: CaseArrays, t: int, graph, sub, centre: np.ndarray) -> np.ndarray:
        """The weights of the reaction-law shares on ``sub`` (:func:`~thrsim.learn.features.law_weights`)."""
        reamer = self._reamer(case, t, centre)
        return law_weights(graph, sub, reamer, case.element_cutting_energy_j_m3, self.settings.arch.reaction_prior)

    def _features(self, case: CaseArrays, t: int, graph, sub, alpha_in, centre, active_t, damage_in) -> tuple:
        """The network's inputs on ``sub`` at frame pair t → t + 1, the reamer's head at ``centre`` after the recorded advance."""
        features = self.settings.features
        return frame_arrays(
            graph,
            sub,
            alpha_in,
            self._reamer(case, t, centre),
            features.feature_set,
            self.threshold,
            active_t,
            damage_in,
            features.corners,
            case.element_cutting_energy_j_m3,
        )

    def _sample(self, index: int, rng: np.random.Generator | None):
        """((subgraph, α in, features), D in or None, α(t+1), D(t+1) or None) on the subgraph's nodes, and
        the next frame's (reaction, torque, feed) (see :func:`next_reaction`), the case's push and hold damping."""
        case_index, t = self.samples[index]
        case = self.train_cases[case_index]
        pushed = self._pushed_steps(int(t), rng)
        with_damage = self.settings.features.damage
        damage_t: np.ndarray | None
        if pushed:
            state = self._pushed_state(case, int(t), pushed)
            alpha_t, damage_t = state.alpha, state.damage
        else:
            alpha_t, damage_t = case.alpha[t], (case.damage[t] if with_damage else None)
        centre = case.positions[t + 1].copy()
        if rng is not None and self.settings.train.position_noise_mm > 0:
            centre += rng.normal(0.0, self.settings.train.position_noise_mm * 1e-3, 3)
        graph = self.graphs[case.case_id]
        active_t = alpha_t >= self.threshold
        sub = select_subgraph(graph, self.settings.features, active_t, centre, case.teeth_radius_m)
        alpha_in = alpha_t[sub.nodes].astype(np.float32)
        active = alpha_in >= self.threshold
        noise = self.settings.train
        alpha_in = self._noisy(alpha_in, active, self.threshold, rng, noise.alpha_noise)
        damage_sigma = noise.alpha_noise if noise.damage_noise is None else noise.damage_noise
        damage_in = (
            None
            if not with_damage or damage_t is None
            else self._noisy(damage_t[sub.nodes].astype(np.float32), active, 0.0, rng, damage_sigma)
        )
        arrays = self._features(case, int(t), graph, sub, alpha_in, centre, active_t, damage_in)
        damage_next = case.damage[t + 1][sub.nodes] if with_damage else None
        return (
            (sub, alpha_in, arrays),
            damage_in,
            case.alpha[t + 1][sub.nodes],
            damage_next,
            (*next_reaction(case, int(t) + 1, self.threshold), self.pushes[case.case_id], case.hold.axial_damping_n_s_m)
            if case.case_id in self.reaction_case_ids
            else (math.nan,) * 5,
            self._law_weights(case, int(t), graph, sub, centre),
        )

    def _overshoot_sample(self, index: int, rng: np.random.Generator):
        """The law's input at a frame pair of a law case with the reamer moved deeper along its axis than the
        solver's (``train.overshoot_mm``), with the case's push; None where the reamer is not seated
        (its recorded reaction under half the push: approaching, the bone ahead may still give way)."""
        case_index, t = self.samples[index]
        case = self.train_cases[case_index]
        if case.case_id not in self.reaction_case_ids:
            return None
        push = self.pushes[case.case_id]
        reaction = next_reaction(case, int(t) + 1, self.threshold)[0]
        if not reaction >= 0.5 * push:
            return None
        low, high = self.settings.train.overshoot_mm
        centre = case.positions[t + 1] + rng.uniform(low, high) * 1e-3 * case.axis
        graph, alpha_t = self.graphs[case.case_id], case.alpha[t]
        active_t = alpha_t >= self.threshold
        sub = select_subgraph(graph, self.settings.features, active_t, centre, case.teeth_radius_m)
        if sub.n_region == 0:
            return None
        alpha_in = alpha_t[sub.nodes].astype(np.float32)
        damage_in = case.damage[t][sub.nodes].astype(np.float32) if self.settings.features.damage and case.damage is not None else None
        arrays = self._features(case, int(t), graph, sub, alpha_in, centre, active_t, damage_in)
        weights = self._law_weights(case, int(t), graph, sub, centre)
        return (sub, alpha_in, arrays), damage_in, (push, 0.0, 0.0, push, case.hold.axial_damping_n_s_m), weights

    def _overshoot_batch(self, chosen: np.ndarray, rng: np.random.Generator) -> GraphBatch | None:
        """The overshoot constraint's inputs for the drawn frame pairs of seated law cases (None: none drawn)."""
        drawn = [d for d in (self._overshoot_sample(int(i), rng) for i in chosen) if d is not None]
        if not drawn:
            return None
        with_damage = self.settings.features.damage
        return batch([d[0] for d in drawn], [d[1] for d in drawn] if with_damage else None, [d[2] for d in drawn], [d[3] for d in drawn])

    def _batch(self, drawn: list) -> tuple:
        """Network inputs, α(t+1) and D(t+1) (None without damage) of drawn samples."""
        with_damage = self.settings.features.damage
        head = self.settings.arch.reaction_head
        reaction, weights = ([d[4] for d in drawn], [d[5] for d in drawn]) if head else (None, None)
        inputs = batch([d[0] for d in drawn], [d[1] for d in drawn] if with_damage else None, reaction, weights)
        alpha_next = torch.from_numpy(np.concatenate([d[2] for d in drawn]).astype(np.float32))
        damage_next = torch.from_numpy(np.concatenate([d[3] for d in drawn]).astype(np.float32)) if with_damage else None
        return inputs, alpha_next, damage_next

    def _fit_normalisers(self) -> None:
        rng = np.random.default_rng([self.settings.train.seed, 10**6])
        chosen = rng.permutation(len(self.samples))[: self.settings.train.normaliser_samples]
        inputs, _, _ = self._batch([self._sample(int(i), None) for i in chosen])
        self.gn.fit_normalisers(inputs)
        self.mlp.fit_normalisers(inputs)

    def _learning_rate(self, epoch: int) -> float:
        t = self.settings.train
        span = max(1, t.epochs - 1)
        return t.learning_rate * (t.final_learning_rate / t.learning_rate) ** (min(epoch, span) / span)

    def train_epoch(self, on_batch: Callable[[int, int], None] | None = None) -> tuple[float, float]:
        t = self.settings.train
        epoch = self.epoch
        rng = np.random.default_rng([t.seed, epoch])
        torch.manual_seed(t.seed * 100_003 + epoch)
        order = self._epoch_order(rng)
        for optimiser in self.optimisers.values():
            for group in optimiser.param_groups:
                group["lr"] = self._learning_rate(epoch)
        self.gn.train()
        self.mlp.train()
        totals = {"gn": 0.0, "mlp": 0.0}
        batches = math.ceil(len(order) / t.batch_size)
        for b in range(batches):
            chosen = order[b * t.batch_size : (b + 1) * t.batch_size]
            inputs, alpha_next, damage_next = self._batch([self._sample(int(i), rng) for i in chosen])
            overshoot = self._overshoot_batch(chosen, rng) if t.overshoot_loss_weight > 0.0 and self.settings.arch.reaction_head else None
            for name, model in (("gn", self.gn), ("mlp", self.mlp)):
                optimiser = self.optimisers[name]
                optimiser.zero_grad(set_to_none=True)
                loss = model.loss(inputs, alpha_next, damage_next)
                if overshoot is not None:
                    loss = loss + t.overshoot_loss_weight * model.overshoot_loss(overshoot)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), t.gradient_clip)
                optimiser.step()
                totals[name] += float(loss.detach()) / batches
            if on_batch is not None:
                on_batch(b + 1, batches)
        self.epoch += 1
        return totals["gn"], totals["mlp"]

    def _epoch_order(self, rng: np.random.Generator) -> np.ndarray:
        """The frame pairs of one epoch, shuffled: all of them or ``max_samples_per_epoch``; with
        ``law_case_share``, that share drawn from the reaction law's cases (repeated if they hold fewer)."""
        t = self.settings.train
        count = len(self.samples) if t.max_samples_per_epoch is None else min(t.max_samples_per_epoch, len(self.samples))
        if t.law_case_share is None:
            return rng.permutation(len(self.samples))[:count]
        in_law = np.array([self.train_cases[c].case_id in self.reaction_case_ids for c in self.samples[:, 0]])
        law, rest = np.flatnonzero(in_law), np.flatnonzero(~in_law)
        n_law = round(t.law_case_share * count) if len(rest) else count
        drawn = np.concatenate([rng.choice(law, n_law, replace=n_law > len(law)), rng.permutation(rest)[: count - n_law]])
        return rng.permutation(drawn)

    def validate(self) -> float | None:
        """Micro F1 of newly removed elements after tool-forced rollouts from frame 0 of each validation case."""
        if not self.validation:
            return None
        counts = Counts()
        for case in self.validation:
            step = self._step(self.gn, case)
            horizon = min(self.settings.train.validation_horizon, case.frames - 1)
            masks, _ = rollout(step, case, 0, horizon, self.threshold, None)
            start = case.alpha[0] < self.threshold
            counts.add(masks[-1] & ~start, (case.alpha[horizon] < self.threshold) & ~start)
        self.gn.train()
        return counts.f1

    # checkpoints -------------------------------------------------------------------------
    def identity(self) -> str:
        identity = {
            "settings": self.settings.model_dump(mode="json"),
            "cases": [c.case_id for c in self.train_cases],
            "mesh": sorted({graph.digest for graph in self.graphs.values()}),
        }
        if self.init_digest is not None:
            identity["init"] = self.init_digest
        return config_hash(identity)

    def save_checkpoint(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        tensors = {f"gn.{k}": v.detach().contiguous() for k, v in self.gn.state_dict().items()}
        tensors.update({f"mlp.{k}": v.detach().contiguous() for k, v in self.mlp.state_dict().items()})
        groups = {}
        for name, optimiser in self.optimisers.items():
            state = optimiser.state_dict()
            for index, entry in state["state"].items():
                for key, value in entry.items():
                    tensors[f"opt.{name}.{index}.{key}"] = torch.as_tensor(value).detach().clone().contiguous()
            groups[name] = state["param_groups"]
        with atomic_path(folder / "state.safetensors") as tmp:
            tmp.write_bytes(tensor_bytes(tensors))  # a full disk: an OSError, as model_dir writes
        progress = {"identity": self.identity(), "epoch": self.epoch, "history": self.history, "param_groups": groups}
        with atomic_path(folder / "progress.json") as tmp:
            tmp.write_text(json.dumps(progress, indent=1))

    def load_checkpoint(self, folder: Path) -> bool:
        """Resume from ``folder`` when it holds a checkpoint of this very run; False when there is none."""
        progress_file, state_file = folder / "progress.json", folder / "state.safetensors"
        if not (progress_file.is_file() and state_file.is_file()):
            return False
        progress = json.loads(progress_file.read_text())
        if progress.get("identity") != self.identity():
            raise ThrsimInputError(f"{folder} holds a checkpoint of another training run (other data or settings); use another", "out")
        tensors = load_tensors(str(state_file))
        self.gn.load_state_dict({k[3:]: v for k, v in tensors.items() if k.startswith("gn.")})
        self.mlp.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("mlp.")})
        for name, optimiser in self.optimisers.items():
            state: dict = {}
            prefix = f"opt.{name}."
            for key, value in tensors.items():
                if key.startswith(prefix):
                    index, field = key[len(prefix) :].split(".", 1)
                    state.setdefault(int(index), {})[field] = value
            optimiser.load_state_dict({"state": state, "param_groups": progress["param_groups"][name]})
        self.epoch = int(progress["epoch"])
        self.history = list(progress["history"])
        return True

    def run(
        self,
        checkpoint_dir: Path | None,
        on_epoch: Callable[[EpochReport], None] | None = None,
        on_batch: Callable[[int, int], None] | None = None,
    ) -> float:
        """Train up to the configured epochs (or the time budget); return training seconds this run."""
        started = time.perf_counter()
        budget = self.settings.train.max_minutes
        while self.epoch < self.settings.train.epochs:
            epoch_start = time.perf_counter()
            gn_loss, mlp_loss = self.train_epoch(on_batch)
            f1 = self.validate()
            seconds = time.perf_counter() - epoch_start
            self.history.append({"epoch": self.epoch, "gn_loss": gn_loss, "mlp_loss": mlp_loss, "validation_f1": f1, "seconds": seconds})
            if checkpoint_dir is not None:
                self.save_checkpoint(checkpoint_dir)
            if on_epoch is not None:
                on_epoch(EpochReport(self.epoch, self.settings.train.epochs, gn_loss, mlp_loss, f1, seconds))
            if budget is not None and time.perf_counter() - started > budget * 60:
                break
        return time.perf_counter() - started


#: frames the reaction targets are averaged over: the solver's reaction comes in element-sized bursts
#: (a median frame's under 1 N, one in a hundred over 100 N), its mean over a tenth of a second does not
REACTION_FRAMES = 6


def next_reaction(case: CaseArrays, frame: int, threshold: float) -> tuple[float, float, float]:
    """The mean reaction (N), torque (N·m) and feed (m/s) over the :data:`REACTION_FRAMES` frames after
    ``frame`` (fewer at the case's end), which the law the network sees at ``frame`` predicts; NaN
    past the case's end or where the case records none. A stall (slower than :data:`STALL_FEED_M_S`
    and no element removed) has feed 0; a slow frame that cuts (a seated whole socket's) at least 1 µm/s."""
    if case.reaction_n is None or case.motor_torque_n_m is None or frame + 1 >= case.frames:
        return (math.nan, math.nan, math.nan)
    last = min(case.frames - 1, frame + REACTION_FRAMES)
    feed = float((case.positions[last] - case.positions[frame]) @ case.axis) / ((last - frame) * case.frame_dt_s)
    if feed < STALL_FEED_M_S:
        cut = bool(((case.alpha[last] < threshold) & (case.alpha[frame] >= threshold)).any())
        feed = max(feed, 1e-6) if cut else 0.0
    window = slice(frame + 1, last + 1)
    return (float(case.reaction_n[window].mean()), float(case.motor_torque_n_m[window].mean()), feed)


def train_advance(train: list[CaseArrays], held_out: list[CaseArrays], seed: int, trees: int = 100, kind: str = LOWEST_CV):
    """Fit the advance regressor on the training cases; the table scores the held-out ones."""
    parts = [case_samples(c) for c in train]
    X = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    groups = np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)])
    held_X: np.ndarray | None
    held_y: np.ndarray | None
    if held_out:
        held = [case_samples(c) for c in held_out]
        held_X, held_y = np.concatenate([h[0] for h in held]), np.concatenate([h[1] for h in held])
    else:
        held_X = held_y = None
    return fit_advance(X, y, groups, held_X, held_y, seed, trees, kind)
