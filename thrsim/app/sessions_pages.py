"""The trainees' record on the web: the session list, a trainee's learning curves, study exports and
the post-session questionnaire.

* ``GET /sessions``: every saved session (trainee, mode, date, duration, score) with its report;
* ``GET /trainee/<id>``: each metric across that trainee's sessions, one small inline SVG chart
  per metric (no script, no library), with the competency level where the metric has one;
* ``GET /api/sessions.csv`` and ``/api/sessions.json``: every session's metrics for studies
  (:mod:`thrsim.report.record`; the same as ``thrsim sessions export``);
* ``GET /api/questionnaire``: the Likert items; ``POST /api/sessions/<id>/questionnaire`` stores a
  trainee's answers in that session's file (:mod:`thrsim.session.questionnaire`). It takes JSON only
  and, when the browser names an origin, only this trainer's: another site's page cannot answer.
"""

from __future__ import annotations

import html
import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from urllib.parse import quote, urlsplit

from fastapi import HTTPException, Request
from fastapi.responses import HTMLResponse, JSONResponse, Response
from starlette.concurrency import run_in_threadpool

from thrsim.app.controls import TRAINEE_PATTERN
from thrsim.errors import ThrsimInputError
from thrsim.report.record import competency, metric_names, of_trainee, session_files, summaries, to_csv, to_json
from thrsim.report.thresholds import Thresholds
from thrsim.session.questionnaire import ITEMS, SCALE, write_questionnaire

_SESSION_ID = re.compile(r"^[0-9]{8}T[0-9]{6}Z-[0-9a-f]{6}$")
_STYLE = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
nav a{margin-right:1em}table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}
th{background:#f2f2f2}.muted{color:#777}.charts{display:flex;flex-wrap:wrap;gap:1em}
figure{margin:0;border:1px solid #ddd;padding:.4em}figcaption{font-size:.9em;max-width:300px}
"""
#: plain words for the metrics the reports give (others are shown by their name)
LABELS = {
    "score_percent": "Score (% of the maximum)",
    "landmarks_acquired": "Landmarks acquired",
    "acquisition_error_mean_mm": "Probe placement: mean distance to the landmarks (mm)",
    "acquisition_error_max_mm": "Probe placement: worst distance to a landmark (mm)",
    "registration_rms_mm": "Registration fit error, RMS (mm)",
    "median_time_per_landmark_s": "Median time per landmark (s)",
    "registration_time_s": "Time to register all landmarks (s)",
    "retakes": "Landmarks retaken",
    "time_in_zone_fraction": "Share of aiming time inside the safe zone",
    "confirmed_cup_distance_deg": "Confirmed cup: degrees outside the safe zone",
    "markers_visible_fraction": "Share of time every marker was seen",
    "perforations": "Perforations",
    "undos": "Undos",
    "restores": "Bone restored",
    "push_mean_n": "Mean push (N)",
    "reamer_path_length_mm": "Reamer path length (mm)",
    "push_out_of_range_fraction": "Share of time pushing outside the trained range",
    "inclination_error_deg": "Cavity axis: inclination off the plan (°)",
    "anteversion_error_deg": "Cavity axis: anteversion off the plan (°)",
    "confirmed_inclination_error_deg": "Confirmed cup: inclination off the plan (°)",
    "confirmed_anteversion_error_deg": "Confirmed cup: anteversion off the plan (°)",
    "within_5deg_fraction": "Share of reaming time within 5° of the plan",
    "within_10deg_fraction": "Share of reaming time within 10° of the plan",
    "cavity_diameter_error_mm": "Cavity diameter against the cup (mm)",
    "cavity_depth_error_mm": "Cavity floor beyond (+) or short of (−) the plan (mm)",
    "over_reaming_mm": "Over-reaming: bone removed beyond the planned cup (mm)",
    "under_reaming_mm": "Under-reaming: bone left inside the planned cup (mm)",
    "medial_wall_remaining_mm": "Medial wall left (mm)",
}


def label(metric: str) -> str:
    return LABELS.get(metric, metric.replace("_", " "))


def _page(title: str, body: str) -> HTMLResponse:
    links = '<nav><a href="/">Navigation trainer</a><a href="/reaming">Reaming trainer</a><a href="/sessions">Sessions</a></nav>'
    return HTMLResponse(
        f"<!doctype html><html lang=en><head><meta charset=utf-8><title>thrsim · {html.escape(title)}</title>"
        f"<style>{_STYLE}</style></head><body>{links}<h1>{html.escape(title)}</h1>{body}</body></html>",
        headers={"cache-control": "no-store"},
    )


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "—"
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes} min {rest:02d} s" if minutes else f"{rest} s"


def _score(row: dict) -> str:
    return "not scored" if row["score"] is None else f"{row['score']:g} / {row['max_score']:g}"


def trainee_link(trainee: str) -> str:
    return f"/trainee/{quote(trainee.strip().casefold(), safe='')}"


def sessions_page(rows: list[dict]) -> HTMLResponse:
    lines = []
    for row in reversed(rows):  # newest first
        if "error" in row:
            lines.append(f"<tr><td colspan=6 class=muted>{html.escape(row['session'])}: {html.escape(row['error'])}</td></tr>")
            continue
        who = (
            f'<a href="{trainee_link(row["trainee"])}">{html.escape(row["trainee"])}</a>'
            if row["trainee"]
            else '<span class="muted">not named</span>'
        )
        interrupted = " (interrupted)" if row["interrupted"] else ""
        lines.append(
            f'<tr data-session="{html.escape(row["session"])}"><td>{who}</td><td>{html.escape(row["mode"])}</td>'
            f"<td>{html.escape(row['started_utc'][:16].replace('T', ' '))} UTC</td><td>{_duration(row['duration_s'])}{interrupted}</td>"
            f'<td>{_score(row)}</td><td><a href="/sessions/{html.escape(row["session"])}/report">report</a></td></tr>'
        )
    table = (
        "<table id=sessions><thead><tr><th>trainee</th><th>mode</th><th>started</th><th>duration</th><th>score</th><th></th></tr></thead>"
        f"<tbody>{''.join(lines)}</tbody></table>"
        if lines
        else "<p>No session saved yet: a session is saved when its trainee ends it (End session &amp; get report).</p>"
    )
    exports = (
        '<p>For studies: <a href="/api/sessions.csv">every session\'s metrics as CSV</a> · <a href="/api/sessions.json">as JSON</a></p>'
    )
    return _page("Sessions", table + exports)


def _chart(metric: str, points: list[tuple[int, float, str]], level: list | None) -> str:
    """One metric across sessions: a small inline SVG line chart, the competency level dashed."""
    width, height, left, right, top, bottom = 300, 150, 42, 10, 10, 28
    values = [v for _, v, _ in points] + ([float(level[0])] if level else [])
    low, high = min(values), max(values)
    if high - low < 1e-9:
        low, high = low - 1.0, high + 1.0
    pad = 0.08 * (high - low)
    low, high = low - pad, high + pad
    count = max(len(points), 2)

    def x(k: int) -> float:
        return left + (width - left - right) * (k / (count - 1))

    def y(value: float) -> float:
        return top + (height - top - bottom) * (1 - (value - low) / (high - low))

    parts = [
        f'<line x1="{left}" y1="{height - bottom}" x2="{width - right}" y2="{height - bottom}" stroke="#999"/>',
        f'<line x1="{left}" y1="{top}" x2="{left}" y2="{height - bottom}" stroke="#999"/>',
        f'<text x="{left - 4}" y="{y(high - pad) + 4:.1f}" font-size="10" text-anchor="end">{high - pad:.3g}</text>',
        f'<text x="{left - 4}" y="{y(low + pad) + 4:.1f}" font-size="10" text-anchor="end">{low + pad:.3g}</text>',
        f'<text x="{(left + width - right) / 2}" y="{height - 4}" font-size="10" text-anchor="middle">session</text>',
    ]
    if level:
        threshold, kind = float(level[0]), level[1]
        words = f"competent: {'≤' if kind == 'max' else '≥'} {threshold:g}"
        parts.append(
            f'<line class="competency" x1="{left}" y1="{y(threshold):.1f}" x2="{width - right}" y2="{y(threshold):.1f}" '
            f'stroke="#0a7a3a" stroke-dasharray="5 3"><title>{html.escape(words)}</title></line>'
            f'<text x="{width - right}" y="{y(threshold) - 3:.1f}" font-size="10" text-anchor="end" fill="#0a7a3a">{html.escape(words)}</text>'
        )
    path = " ".join(f"{'M' if i == 0 else 'L'}{x(k):.1f},{y(v):.1f}" for i, (k, v, _) in enumerate(points))
    parts.append(f'<path d="{path}" fill="none" stroke="#1f77b4" stroke-width="1.5"/>')
    for k, value, when in points:
        parts.append(
            f'<circle class="point" cx="{x(k):.1f}" cy="{y(value):.1f}" r="3" fill="#1f77b4"><title>{html.escape(when)}: {value:.3g}</title></circle>'
        )
        parts.append(f'<text x="{x(k):.1f}" y="{height - bottom + 12}" font-size="10" text-anchor="middle">{k + 1}</text>')
    svg = f'<svg width="{width}" height="{height}" viewBox="0 0 {width} {height}" role="img" aria-label="{html.escape(label(metric))}">{"".join(parts)}</svg>'
    return f'<figure data-metric="{html.escape(metric)}">{svg}<figcaption>{html.escape(label(metric))}</figcaption></figure>'


def trainee_page(trainee: str, rows: list[dict]) -> HTMLResponse:
    mine = of_trainee(rows, trainee)
    if not mine:
        raise HTTPException(404, f"no saved session of trainee {trainee!r}")
    name = mine[-1]["trainee"]
    levels = competency(mine)
    charts = []
    for mode in dict.fromkeys(r["mode"] for r in mine):
        sessions = [r for r in mine if r["mode"] == mode]
        metrics = ["score_percent", *metric_names(sessions)]
        figures = []
        for metric in metrics:
            points = []
            for k, row in enumerate(sessions):
                if metric == "score_percent":
                    value = None if row["score"] is None else 100.0 * row["score"] / row["max_score"]
                else:
                    value = row["metrics"].get(metric)
                if isinstance(value, (int, float)) and math.isfinite(value):
                    points.append((k, float(value), row["started_utc"][:16].replace("T", " ")))
            if points:
                figures.append(_chart(metric, points, levels.get(metric)))
        listing = "".join(
            f"<li>{k + 1}: {html.escape(r['started_utc'][:16].replace('T', ' '))} UTC · {_score(r)} · "
            f'<a href="/sessions/{html.escape(r["session"])}/report">report</a></li>'
            for k, r in enumerate(sessions)
        )
        charts.append(
            f'<section data-mode="{html.escape(mode)}"><h2>{html.escape(mode)} · {len(sessions)} sessions</h2>'
            f'<div class="charts">{"".join(figures)}</div><ol class="muted">{listing}</ol></section>'
        )
    intro = (
        "<p>Each chart follows one measure across this trainee's sessions, oldest first; the dashed green line is the "
        "level a competent trainee reaches, where the measure has one (the full-points level of its criterion in the report).</p>"
    )
    return _page(f"Trainee {name}", intro + "".join(charts))


def _same_site(request: Request) -> bool:
    origin = request.headers.get("origin")
    return origin is None or urlsplit(origin).netloc == request.headers.get("host")


def record_routes(sessions_dir: Path, thresholds: Thresholds | None = None) -> list[tuple[str, Callable, list[str]]]:
    """(path, handler, methods) of the record's routes over the sessions folder, scores and competency
    levels judged against ``thresholds`` (the server's, as its reports are; None: the shipped defaults)."""

    def rows() -> list[dict]:
        return summaries(session_files([sessions_dir]), skip_unreadable=True, thresholds=thresholds)

    def sessions() -> HTMLResponse:
        return sessions_page(rows())

    def trainee(trainee_id: str) -> HTMLResponse:
        if len(trainee_id) > 40 or not re.fullmatch(TRAINEE_PATTERN, trainee_id):
            raise HTTPException(404, "not a trainee name or ID")
        return trainee_page(trainee_id, rows())

    def sessions_csv() -> Response:
        return Response(
            to_csv(rows()), media_type="text/csv; charset=utf-8", headers={"content-disposition": 'attachment; filename="sessions.csv"'}
        )

    def sessions_json() -> JSONResponse:
        return JSONResponse(to_json(rows()))

    def questionnaire_items() -> dict:
        return {"items": ITEMS, "scale": SCALE}

    async def answer(session_id: str, request: Request) -> JSONResponse:
        if not _same_site(request):
            return JSONResponse({"error": "answers come from this trainer's page only"}, status_code=403)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return JSONResponse({"error": "answers are sent as application/json"}, status_code=415)
        path = sessions_dir / f"{session_id}.h5"
        if not _SESSION_ID.match(session_id) or not path.is_file():
            return JSONResponse({"error": f"no saved session {session_id!r}"}, status_code=404)
        body = await request.body()
        try:
            data = json.loads(body) if len(body) <= 16 * 1024 else None
            if not isinstance(data, dict):
                raise ThrsimInputError("send one JSON object {answers: {item: 1-5}, comment: text} of at most 16 KiB")
            stored = await run_in_threadpool(write_questionnaire, path, data.get("answers", {}), data.get("comment", ""))
        except (ValueError, RecursionError):
            return JSONResponse({"error": "answers are not JSON"}, status_code=422)
        except ThrsimInputError as error:
            return JSONResponse({"error": str(error)}, status_code=422)
        return JSONResponse({"saved": True, **stored})

    return [
        ("/sessions", sessions, ["GET"]),
        ("/trainee/{trainee_id}", trainee, ["GET"]),
        ("/api/sessions.csv", sessions_csv, ["GET"]),
        ("/api/sessions.json", sessions_json, ["GET"]),
        ("/api/questionnaire", questionnaire_items, ["GET"]),
        ("/api/sessions/{session_id}/questionnaire", answer, ["POST"]),
    ]
