"""The report's building blocks: a scored criterion, a section of the page, a mode's part of the
assessment, and the HTML pieces sections are made of (a plot as an embedded PNG, a table).

Each mode's report module (:mod:`thrsim.report.navigation`, :mod:`thrsim.report.reaming`) builds
its part from these; :mod:`thrsim.report.document` assembles the parts. Neither imports the other.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Criterion:
    """One scored line: what was measured, the rule, and the points it earned."""

    name: str
    measured: str
    rule: str
    points: float
    max_points: float


@dataclass
class Section:
    title: str
    body: str  # HTML
    criteria: list[Criterion] = field(default_factory=list)


@dataclass
class Part:
    """One mode's share of a session's assessment: its criteria, events and metrics as data, and
    ``sections``, which builds its part of the page (plots take time: only the page asks);
    ``competency``: metric name → (threshold, "max" or "min"), the level a competent trainee reaches,
    for the metrics that have one (a trainee's learning curve draws it)."""

    criteria: list[Criterion]
    events: list[dict]
    metrics: dict
    sections: Callable[[], list[Section]]
    competency: dict[str, tuple[float, str]] = field(default_factory=dict)


def figure_png(figure) -> str:
    """An <img> of a matplotlib figure, as a base64 PNG data URI; closes the figure."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    plt.close(figure)
    data = base64.b64encode(buffer.getvalue()).decode()
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


def table(header: list[str], rows: Sequence[Sequence[object]]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
