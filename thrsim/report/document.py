"""Report assembly: sections from providers, a criteria table, plots embedded as base64 PNG.

The thesis's review of simulators found that open-surgery trainers lack a detailed
assessment report [2.2.1, criterion i]; this page is that report. It embeds everything (no
script, no external file), so it can be mailed or archived with the session.
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from thrsim.session.file import SessionFile, read_session


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


SectionProvider = Callable[[SessionFile], list[Section]]


def figure_png(figure) -> str:
    """An <img> of a matplotlib figure, as a base64 PNG data URI; closes the figure."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    plt.close(figure)
    data = base64.b64encode(buffer.getvalue()).decode()
    return f'<img alt="plot" src="data:image/png;base64,{data}">'


def table(header: list[str], rows: list[list[object]]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _providers() -> list[SectionProvider]:
    from thrsim.report.navigation import navigation_sections
    from thrsim.report.reaming import reaming_sections

    return [navigation_sections, reaming_sections]


_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1000px;margin:2em auto;padding:0 1em;color:#222}
h1{margin-bottom:0}.meta{color:#666;margin-top:.3em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}
th{background:#f2f2f2}.score{font-size:2em;font-weight:bold}img{max-width:100%}
.pass{color:#0a7a3a}.partial{color:#b07000}.fail{color:#b01818}details{margin:.5em 0}
"""


def render(session: SessionFile, sections: list[Section]) -> str:
    criteria = [c for s in sections for c in s.criteria]
    total, possible = sum(c.points for c in criteria), sum(c.max_points for c in criteria)
    rows = []
    for c in criteria:
        grade = "pass" if c.points == c.max_points else "partial" if c.points > 0 else "fail"
        rows.append(
            f'<tr class="{grade}"><td>{html.escape(c.name)}</td><td>{html.escape(c.measured)}</td>'
            f"<td>{html.escape(c.rule)}</td><td>{c.points:g} / {c.max_points:g}</td></tr>"
        )
    summary = (
        f'<p class="score">{total:g} / {possible:g}</p>'
        "<table><thead><tr><th>criterion</th><th>measured</th><th>rule</th><th>points</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
        "<p>The criteria and their thresholds are thrsim's trainer defaults: the thesis asks for a detailed "
        "assessment report [2.2.1] but gives no scoring rubric for it.</p>"
    )
    attrs = session.attrs
    versions = ", ".join(f"{k} {v}" for k, v in session.versions.items())
    interrupted = " · <b>interrupted</b>: the server stopped before the session ended" if attrs.get("interrupted") else ""
    parts = [
        f"<h1>Assessment report</h1><p class=meta>session {html.escape(str(attrs.get('session_id', session.path.stem)))} · "
        f"mode {html.escape(str(attrs.get('mode')))} · started {html.escape(str(attrs.get('started_utc')))} · "
        f"duration {float(attrs.get('duration_s', 0.0)):.1f} s{interrupted}</p>",
        f"<h2>Summary score</h2>{summary}",
    ]
    parts += [f"<h2>{html.escape(s.title)}</h2>{s.body}" for s in sections]
    parts.append(
        f"<details><summary>Provenance</summary><p>{html.escape(versions)}</p>"
        f"<pre>{html.escape(json.dumps(session.settings, indent=1))}</pre></details>"
    )
    return f"<!doctype html><html lang=en><head><meta charset=utf-8><title>thrsim assessment report</title><style>{_STYLE}</style></head><body>{''.join(parts)}</body></html>"


@dataclass(frozen=True)
class Assessment:
    """A session's report page and the criteria it scores."""

    html: str
    criteria: list[Criterion]

    @property
    def score(self) -> float:
        return sum(c.points for c in self.criteria)

    @property
    def max_score(self) -> float:
        return sum(c.max_points for c in self.criteria)


def assess(path: str | Path) -> Assessment:
    """The report and criteria of the session file at ``path`` (ThrsimInputError when it cannot be read)."""
    import matplotlib

    matplotlib.use("Agg")
    session = read_session(path)
    sections = [section for provider in _providers() for section in provider(session)]
    return Assessment(render(session, sections), [c for s in sections for c in s.criteria])


def build_report(path: str | Path) -> str:
    """The report page of the session file at ``path`` (ThrsimInputError when it cannot be read)."""
    return assess(path).html
