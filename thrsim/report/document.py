"""Report assembly: the assessment as data (score, criteria, events, metrics) and the page built
on it (sections from each mode, a criteria table, plots embedded as base64 PNG).

The thesis's review of simulators found that open-surgery trainers lack a detailed
assessment report [2.2.1, criterion i]; this page is that report. It embeds everything (no
script, no external file), so it can be mailed or archived with the session. A session where
nothing assessable was done (no landmark, no cup, no bone reamed) is not scored.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path

from thrsim.report.parts import Criterion, Part, Section
from thrsim.report.thresholds import Thresholds, default_thresholds
from thrsim.session.file import SessionFile, read_session


@dataclass
class Assessment:
    """A session's assessment: ``score`` and ``max_score`` are None when nothing was done to score."""

    criteria: list[Criterion]
    events: list[dict]
    metrics: dict
    competency: dict[str, tuple[float, str]] = field(default_factory=dict)  # see Part.competency

    @property
    def score(self) -> float | None:
        return sum(c.points for c in self.criteria) if self.criteria else None

    @property
    def max_score(self) -> float | None:
        return sum(c.max_points for c in self.criteria) if self.criteria else None

    def as_json(self) -> dict:
        """``thrsim report --json``: score, max_score, criteria, events, metrics."""
        return {
            "score": self.score,
            "max_score": self.max_score,
            "criteria": [vars(c) for c in self.criteria],
            "events": self.events,
            "metrics": self.metrics,
        }


_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1000px;margin:2em auto;padding:0 1em;color:#222}
h1{margin-bottom:0}.meta{color:#666;margin-top:.3em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}
th{background:#f2f2f2}.score{font-size:2em;font-weight:bold}img{max-width:100%}
.pass{color:#0a7a3a}.partial{color:#b07000}.fail{color:#b01818}details{margin:.5em 0}
"""


def render(session: SessionFile, assessment: Assessment, sections: list[Section]) -> str:
    rows = []
    for c in assessment.criteria:
        grade = "pass" if c.points == c.max_points else "partial" if c.points > 0 else "fail"
        rows.append(
            f'<tr class="{grade}"><td>{html.escape(c.name)}</td><td>{html.escape(c.measured)}</td>'
            f"<td>{html.escape(c.rule)}</td><td>{c.points:g} / {c.max_points:g}</td></tr>"
        )
    if assessment.score is None:
        summary = '<p class="score">not scored</p><p>Nothing was done in this session that the trainer assesses.</p>'
    else:
        summary = (
            f'<p class="score">{assessment.score:g} / {assessment.max_score:g}</p>'
            "<table><thead><tr><th>criterion</th><th>measured</th><th>rule</th><th>points</th></tr></thead>"
            f"<tbody>{''.join(rows)}</tbody></table>"
            "<p>The thresholds are the trainer's competency thresholds file (thrsim's defaults, each with its published "
            "source, or an instructor's): the thesis asks for a detailed assessment report [2.2.1] but gives no scoring rubric for it.</p>"
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


def _parts(session: SessionFile, thresholds: Thresholds | None) -> list[Part]:
    """Every mode's part of the session's report (a mode whose group the file lacks has none),
    scored against ``thresholds`` (None: the shipped defaults)."""
    import matplotlib

    from thrsim.app.modes import MODES

    matplotlib.use("Agg")
    thresholds = thresholds or default_thresholds()
    return [part for mode in MODES.values() if (part := mode.report_part(session, thresholds)) is not None]


def _assessment(parts: list[Part]) -> Assessment:
    return Assessment(
        [c for p in parts for c in p.criteria],
        [e for p in parts for e in p.events],
        {k: v for p in parts for k, v in p.metrics.items()},
        {k: v for p in parts for k, v in p.competency.items()},
    )


def build_assessment(path: str | Path, thresholds: Thresholds | None = None, session: SessionFile | None = None) -> Assessment:
    """The assessment of the session file at ``path`` as data (ThrsimInputError when it cannot be read),
    scored against ``thresholds`` (None: the shipped defaults); ``session``: that file already read."""
    return _assessment(_parts(session or read_session(path), thresholds))


def build_report(path: str | Path, thresholds: Thresholds | None = None) -> str:
    """The report of the session file at ``path`` (ThrsimInputError when it cannot be read), scored as :func:`build_assessment`."""
    session = read_session(path)
    parts = _parts(session, thresholds)
    return render(session, _assessment(parts), [section for part in parts for section in part.sections()])
