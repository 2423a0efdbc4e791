"""``--window POLAR,AZIMUTH[,HALF_ANGLE]``: a window of the socket, shared by ``thrsim mesh`` and ``thrsim fem``."""

from __future__ import annotations

import math

from thrsim.config import SocketConfig
from thrsim.errors import ThrsimInputError

_FIELDS = SocketConfig.model_fields
WINDOW_HELP = (
    "mesh only a window of the socket (socket only): its centre POLAR degrees from the pole, AZIMUTH degrees about the "
    "socket axis from anterior toward superior, optional HALF_ANGLE degrees across "
    f"[default half-angle: {_FIELDS['window_half_angle_deg'].default:g}]"
)
WINDOW_METAVAR = "POLAR,AZIMUTH[,HALF_ANGLE]"


def window_settings(text: str | None) -> dict[str, float]:
    """The socket settings a ``--window`` value names ({} when none is given); one-line errors."""
    if text is None:
        return {}
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise ThrsimInputError(f"--window must be POLAR,AZIMUTH or POLAR,AZIMUTH,HALF_ANGLE in degrees, got {text!r}")
    polar, azimuth = values[:2]
    half_angle = values[2] if len(values) == 3 else _FIELDS["window_half_angle_deg"].default
    if not 0.0 <= polar <= 90.0:
        raise ThrsimInputError(f"--window: the polar angle must lie in [0, 90] degrees (0 is the pole, 90 the rim), got {polar:g}")
    if not -360.0 <= azimuth <= 360.0:
        raise ThrsimInputError(f"--window: the azimuth must lie in [-360, 360] degrees, got {azimuth:g}")
    if not 0.0 < half_angle <= 45.0:
        raise ThrsimInputError(f"--window: the half-angle must lie in (0, 45] degrees, got {half_angle:g}")
    return {"window_polar_deg": polar, "window_azimuth_deg": azimuth, "window_half_angle_deg": half_angle}
