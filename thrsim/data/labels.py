"""The element label α [7.2.1, eq. 47] and the removed-element rule.

α = 1 − (PEEQ + τ·max(0, 1 − μ·σ_M/1e7)), clipped to [0, 1], with μ = 0.38, τ = 0.42 and the
von Mises stress σ_M in Pa; removed elements (STATUS = 0) get α = 0. An element counts as
removed when α < 0.3. All constants come from :class:`thrsim.config.LabelConfig`.
"""

from __future__ import annotations

import numpy as np

from thrsim.config import LabelConfig

DEFAULT_LABELS = LabelConfig()


def alpha(peeq, von_mises, status=None, config: LabelConfig = DEFAULT_LABELS) -> np.ndarray:
    """α per element (float32, same shape as ``peeq``); 0 where ``status`` is 0."""
    peeq = np.asarray(peeq, dtype=np.float64)
    vm = np.asarray(von_mises, dtype=np.float64)
    stress_term = np.maximum(0.0, 1.0 - config.mu * vm / config.von_mises_scale_pa)
    value = np.clip(1.0 - (peeq + config.tau * stress_term), 0.0, 1.0)
    if status is not None:
        value = np.where(np.asarray(status) == 0, 0.0, value)
    return value.astype(np.float32)


def removed(alpha_values, config: LabelConfig = DEFAULT_LABELS) -> np.ndarray:
    """Boolean mask of elements that count as removed (α below the threshold, 0.3 by default)."""
    return np.asarray(alpha_values) < config.removed_threshold
