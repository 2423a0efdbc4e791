"""The element label α [7.2.1, eq. 47] and the removed-element rule.

α = 1 − (PEEQ + τ·max(0, 1 − μ·σ_M/1e7)), clipped to [0, 1], with μ = 0.38, τ = 0.42 and the
von Mises stress σ_M in Pa; removed elements (STATUS = 0) get α = 0. An element counts as
removed when α < 0.3. In a crushable foam (the socket's cancellous bone) plastic strain is
compaction, not material lost, so its damage D stands in PEEQ's place (unless the labels'
``crushed_bone_is_lost``). All constants come from :class:`thrsim.config.LabelConfig`.
"""

from __future__ import annotations

import numpy as np

from thrsim.config import LabelConfig, ReamingCaseConfig
from thrsim.errors import ThrsimInputError
from thrsim.geometry.mesh import TetMesh

DEFAULT_LABELS = LabelConfig()


def alpha(
    peeq, von_mises, status=None, config: LabelConfig = DEFAULT_LABELS, *, damage=None, compacting: np.ndarray | None = None
) -> np.ndarray:
    """α per element (float32, same shape as ``peeq``); 0 where ``status`` is 0. ``compacting``
    (per element, bool) marks the crushable foam's elements, whose ``damage`` (shaped as ``peeq``)
    is read in place of their plastic strain."""
    loss = np.asarray(peeq, dtype=np.float64)
    vm = np.asarray(von_mises, dtype=np.float64)
    if compacting is not None and not config.crushed_bone_is_lost and np.any(compacting):
        if damage is None:
            raise ThrsimInputError("α of a crushable foam's elements needs their damage, which these frames lack")
        loss = np.where(np.asarray(compacting, dtype=bool), np.asarray(damage, dtype=np.float64), loss)
    stress_term = np.maximum(0.0, 1.0 - config.mu * vm / config.von_mises_scale_pa)
    value = np.clip(1.0 - (loss + config.tau * stress_term), 0.0, 1.0)
    if status is not None:
        value = np.where(np.asarray(status) == 0, 0.0, value)
    return value.astype(np.float32)


def removed(alpha_values, config: LabelConfig = DEFAULT_LABELS) -> np.ndarray:
    """Boolean mask of elements that count as removed (α below the threshold, 0.3 by default)."""
    return np.asarray(alpha_values) < config.removed_threshold


def compacting_elements(case_config: object, mesh: TetMesh) -> np.ndarray:
    """(E,) bool: the elements of ``mesh`` that compact when crushed, by a case file's settings
    (the solver's defaults where a setting, or the settings, are absent; a cancellous bone written
    without a ``compaction`` setting is from a solver before 0.5.2, whose cancellous bone did not compact)."""
    from thrsim.physics.reaming_case import compacting_elements as of_case  # Numba: loaded only here

    if not isinstance(case_config, dict):
        case_config = {}
    cancellous = case_config.get("cancellous")
    if isinstance(cancellous, dict) and "compaction" not in cancellous:
        case_config = {**case_config, "cancellous": {**cancellous, "compaction": None}}
    return of_case(ReamingCaseConfig.model_validate({"inclination_deg": 0.0, "anteversion_deg": 0.0, **case_config}), mesh)
