"""Settings of the learned simulator: architecture, features, training; presets ``production`` and ``thesis``.

Everything here is stored in the model card, so a model directory says how it was built.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from thrsim.learn.advance import Kind

FeatureSet = Literal["full", "thesis", "socket"]


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class ArchSettings(_Frozen):
    """Encode–process–decode sizes (hidden-layer widths; every listed layer is Linear + ReLU).

    ``global_block``: update a global latent each step from summed nodes and edges (the thesis's
    full GN block); without it the force is broadcast into the node encoder (cheaper, and the
    sum over a region of varying size carries no meaning). ``residual``: latents are updated
    additively (MeshGraphNets); ``residual_logit``: the output logit is added to logit(α_t), so
    an untrained network already predicts "nothing changes". ``removal_head``: a second output,
    the probability that an active element is removed by the next frame, whose hazard
    −log(1 − p) the rollout accumulates per element (see :mod:`thrsim.learn.learned_simulator`).
    ``reaction_head``: four more outputs, each node's non-negative share of the bone's axial reaction
    and of the motor torque over the next frame, as a part that holds at any feed and a part per
    unit of feed; their sums make the reaction law the push is balanced against (the feed).
    ``reaction_prior``: what weights each node's per-feed shares besides its contact area: "none", or
    "cutting", the reaction and torque per unit feed the solver's cutting law gives the element at its
    place on the teeth (:func:`thrsim.learn.features.law_weights`), which the share then corrects.
    """

    node_encoder: tuple[int, ...] = (32, 32)
    node_core: tuple[int, ...] = (32, 32)
    node_decoder: tuple[int, ...] = (32,)
    edge_encoder: tuple[int, ...] = (32, 32)
    edge_core: tuple[int, ...] = (32, 32)
    global_encoder: tuple[int, ...] = (16,)
    global_core: tuple[int, ...] = ()
    message_passing_steps: int = Field(4, ge=1)
    shared_core: bool = False
    global_block: bool = False
    residual: bool = True
    layer_norm: bool = True
    residual_logit: bool = True
    removal_head: bool = False
    reaction_head: bool = False
    reaction_prior: Literal["none", "cutting"] = "none"
    mlp_baseline: tuple[int, ...] = (32, 32)

    @model_validator(mode="after")
    def _prior_weights_a_law(self) -> ArchSettings:
        if self.reaction_prior != "none" and not self.reaction_head:
            raise ValueError("a reaction prior weights the reaction head's shares: it needs reaction_head")
        return self


class FeatureSettings(_Frozen):
    """Per-frame inputs and the region the network updates.

    ``full``: node = centroid − reamer centre, its axial and radial parts, signed distance to
    the teeth's sphere, cutting speed ω·r, cosine between the axis and the shell normal, distance
    from the acetabular centre (depth across the shell), α, active flag and open-face count; edge = present/broken one-hot + centroid offset and its
    length; global = force vector along D, its magnitude and the reamer's advance this frame.
    ``thesis`` [7.3.1]: node = centroid − reamer centre and α; edge = present/broken one-hot;
    global = force vector.
    ``socket``: the bone frame drops out, so one model serves every window of the socket, every
    reamer size and the whole socket: node = axial and radial parts of centroid − reamer centre,
    signed distance to the teeth's sphere, cutting speed, cosine between the axis and the direction
    from the socket's centre, α, active flag, open faces and log10 of the element's cutting energy
    (its material); edge = present/broken one-hot + centroid offset along the axis, along the
    receiver's radial direction and around the axis, and its length; global = the reamer's advance
    this frame and its teeth radius. No push: a case at a set feed pushes what the bone takes.

    ``damage``: each node also reads its element's damage D(t) and the network predicts D(t+1),
    which the rollout carries as state (never below D(t): damage only grows). α mixes PEEQ and von
    Mises stress only, so without D the network cannot see how close a loaded element is to
    deletion; the solver's own repeatability of newly removed elements one frame on is 96 %.
    Needs cases that record damage (solver 0.4.0 and later).

    ``corners`` (with ``full`` or ``socket``): each node also reads its tetrahedron's four corner distances to
    the teeth's sphere (sorted; negative inside) and its nearest corner's at the previous frame's
    centre. The teeth cut at the nodes, and a centroid cannot tell a tet that pokes one corner
    into the teeth's path from one that lies flat along it.
    """

    feature_set: FeatureSet = "full"
    corners: bool = Field(False, description="node inputs: the tet's corner distances to the teeth's sphere (full and socket sets)")
    damage: bool = Field(False, description="node input D(t) and output D(t+1) (cases must record damage)")
    reach_margin_mm: float = Field(1.0, gt=0, description="front elements whose centroid is within teeth reach + this of the reamer centre")
    front_hops: int = Field(1, ge=0, description="face-hops the updated region grows from the front into the bone")
    halo_hops: int = Field(0, ge=0, description="face-hops of context around the region (not updated)")
    whole_graph: bool = Field(False, description="update every element every frame (the thesis's way)")

    def network_inputs(self) -> dict:
        """What shapes the network's inputs, without the region a step updates (reach, hops, whole
        graph): a warm start may grow the region, never change the inputs."""
        return self.model_dump(exclude={"reach_margin_mm", "front_hops", "halo_hops", "whole_graph"})

    @model_validator(mode="after")
    def _corners_need_the_full_set(self) -> FeatureSettings:
        if self.corners and self.feature_set == "thesis":
            raise ValueError("corners are inputs of the full and socket feature sets only")
        return self


class TrainSettings(_Frozen):
    """Optimisation: Adam, exponential learning-rate decay, Gaussian noise on the input α, and
    pushforward: a share of the inputs come from the Graph Network's own rollout of 1 …
    ``pushforward_steps`` frames (recorded reamer positions, no gradient) from the ground truth,
    so the network learns to continue from the states it produces, not only from the solver's
    (Brandstetter, Worrall and Welling 2022, "Message passing neural PDE solvers")."""

    epochs: int = Field(30, ge=1)
    batch_size: int = Field(4, ge=1)
    learning_rate: float = Field(1e-3, gt=0)
    final_learning_rate: float = Field(1e-4, gt=0)
    gradient_clip: float = Field(1.0, gt=0, description="largest gradient norm per step")
    alpha_noise: float = Field(0.02, ge=0, description="σ of the Gaussian noise on input α (and D, see damage_noise; stable rollouts)")
    damage_noise: float | None = Field(
        None, ge=0, le=1, description="σ of the noise on input D (None: alpha_noise); D grows by 0.01–0.06 a frame under a seated reamer"
    )
    position_noise_mm: float = Field(0.05, ge=0, description="σ of the noise on the reamer centre")
    seed: int = 0
    max_samples_per_epoch: int | None = Field(None, ge=1, description="subsample the frame pairs each epoch")
    normaliser_samples: int = Field(64, ge=1, description="frame pairs whose inputs fix the normalisation")
    validation_horizon: int = Field(30, ge=1, description="frames of the validation rollouts run after each epoch")
    max_minutes: float | None = Field(None, gt=0, description="stop after the epoch that crosses this budget")
    advance_trees: int = Field(100, ge=1, description="trees of the advance regressor's Random Forest (the thesis's 100)")
    advance_kind: Kind | Literal["lowest_cv"] = Field(
        "lowest_cv",
        description="the advance regressor kept: lowest_cv (the lowest cross-validated error of one frame's advance, the thesis's "
        "rule) or a kind by name; svr holds off the training grid where the forest under-advances (the benchmarks page)",
    )
    pushforward_steps: int = Field(
        0, ge=0, description="longest rollout of the network itself that makes a training input (0: ground-truth inputs only)"
    )
    pushforward_fraction: float = Field(0.5, ge=0, le=1, description="share of frame pairs whose input is pushed forward")
    pushforward_from_epoch: int = Field(
        5, ge=0, description="first epoch with pushed-forward inputs (the network must first learn one step)"
    )
    law_from: Literal["pushed", "whole_socket"] = Field(
        "pushed",
        description="the cases a reaction head's law learns from: every pushed case, or the pushed whole sockets only "
        "(a window is held at its cut sides, which stiffens it beyond the socket it is cut from: the benchmarks page)",
    )
    feed_loss_weight: float = Field(
        0.0,
        ge=0,
        le=100,
        description="weight, beside the reaction's, of the error of the feed at which the recorded push meets the law "
        "(log scale; 0: the law learns the reaction alone)",
    )
    feed_loss_scale_mm_s: float = Field(
        0.1,
        gt=0,
        le=100,
        description="v₀ of the feed error's scale log(1 + v/v₀): feeds well below it count linearly (an unbiased fit of a "
        "noisy seated feed), well above by their ratio",
    )
    overshoot_loss_weight: float = Field(
        0.0,
        ge=0,
        le=100,
        description="weight of the overshoot constraint: the reamer moved deeper than the solver's into bone not yet cut "
        "(train.overshoot_mm) must meet a reaction at no feed at least the push (0: off)",
    )
    overshoot_mm: tuple[float, float] = Field(
        (0.3, 1.5), description="the range (mm) the overshoot constraint moves a seated reamer deeper, drawn uniformly"
    )
    law_case_share: float | None = Field(
        None, gt=0, lt=1, description="share of each epoch's frame pairs drawn from the law's cases (None: in proportion to their frames)"
    )

    @field_validator("overshoot_mm")
    @classmethod
    def _overshoot_range(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not 0.0 < value[0] <= value[1] <= 10.0:
            raise ValueError(f"an overshoot range 0 < low ≤ high ≤ 10 mm, got {list(value)}")
        return value


class ModelSettings(_Frozen):
    arch: ArchSettings = ArchSettings()
    features: FeatureSettings = FeatureSettings()
    train: TrainSettings = TrainSettings()


def thesis_arch() -> ArchSettings:
    """The thesis's sizes [7.3.2]: node enc/dec 1×40, node core 2×300, edge enc/dec 2×20, edge core
    1×30, global enc/dec 2×11, global core 1×20, full GN block with sum aggregation, shared core,
    a plain linear output (eq. 48); the MLP baseline is the node core alone. Every MLP ends in a
    LayerNorm as in the graph_nets library's encode-process-decode models the thesis builds on
    (without it the sums over a region's nodes make the latents grow without bound). Only α is read out,
    so the edge and global decoders, which feed nothing, are not built."""
    return ArchSettings(
        node_encoder=(40,),
        node_core=(300, 300),
        node_decoder=(40,),
        edge_encoder=(20, 20),
        edge_core=(30,),
        global_encoder=(11, 11),
        global_core=(20,),
        message_passing_steps=10,
        shared_core=True,
        global_block=True,
        residual=False,
        layer_norm=True,
        residual_logit=False,
        mlp_baseline=(300, 300),
    )


def preset(name: str) -> ModelSettings:
    """``production`` (the patch, sized for an interactive CPU step), ``socket`` (the same network on
    the socket's frame-free inputs) or ``thesis`` (the reference)."""
    if name == "production":
        return ModelSettings(arch=ArchSettings(removal_head=True), features=FeatureSettings(damage=True, corners=True))
    if name == "socket":
        return ModelSettings(
            arch=ArchSettings(removal_head=True, reaction_head=True),
            features=FeatureSettings(feature_set="socket", damage=True, corners=True),
        )
    if name == "thesis":
        return ModelSettings(arch=thesis_arch(), features=FeatureSettings(feature_set="thesis"))
    from thrsim.errors import ThrsimInputError

    raise ThrsimInputError(f"unknown architecture {name!r}: choose production, socket or thesis")


def preset_with_file(name: str, settings_file: str | None) -> dict:
    """The preset ``name``'s settings as a dict, each section updated by ``settings_file``'s (partial,
    nested JSON; what ``thrsim train --arch --settings`` trains); ThrsimInputError on an unknown section."""
    settings = preset(name).model_dump()
    if settings_file is None:
        return settings
    from thrsim.config import read_settings_file
    from thrsim.errors import ThrsimInputError

    for section, values in read_settings_file(settings_file).items():
        if section not in settings or not isinstance(values, dict):
            raise ThrsimInputError(f"{settings_file}: unknown settings section {section!r} (arch, features, train)")
        settings[section].update(values)
    return settings
