"""The trainees' record: every saved session summarised (who, mode, when, how long, score, metrics,
questionnaire), for the session list, a trainee's learning curve and study exports (CSV, JSON).

Scores and competency levels are judged against the thresholds given (an instructor's file, as
``thrsim serve --thresholds`` loaded it; None: the shipped defaults). A summary is computed from the
session file once and kept while the file and the thresholds are unchanged (its size and
modification time), so listing a sessions folder again costs a glance at each file.
"""

from __future__ import annotations

import csv
import io
import math
import threading
from pathlib import Path

from thrsim.errors import ThrsimInputError
from thrsim.report.document import build_assessment
from thrsim.report.thresholds import Thresholds
from thrsim.session.file import read_session
from thrsim.session.questionnaire import ITEMS, read_questionnaire

#: the columns every exported row has, before its metrics and questionnaire answers
COLUMNS = ("session", "trainee", "mode", "started_utc", "duration_s", "interrupted", "score", "max_score")

_CACHE: dict[Path, tuple[tuple[int, int, str], dict]] = {}
_CACHE_LOCK = threading.Lock()


def summarise(path: str | Path, thresholds: Thresholds | None = None) -> dict:
    """One session's summary: the :data:`COLUMNS`, ``metrics``, ``competency`` and ``questionnaire``
    (None when not answered), scored against ``thresholds``; ThrsimInputError when the file cannot be read."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError:
        raise ThrsimInputError(f"{path}: no such session file") from None
    key = (stat.st_mtime_ns, stat.st_size, "" if thresholds is None else thresholds.model_dump_json())
    with _CACHE_LOCK:
        cached = _CACHE.get(path.resolve())
    if cached is not None and cached[0] == key:
        return cached[1]
    session = read_session(path)
    assessment = build_assessment(path, thresholds, session=session)
    attrs = session.attrs
    summary = {
        "session": str(attrs.get("session_id", path.stem)),
        "trainee": str(attrs.get("trainee", "")),
        "mode": str(attrs.get("mode", "")),
        "started_utc": str(attrs.get("started_utc", "")),
        "duration_s": float(attrs.get("duration_s", math.nan)),
        "interrupted": bool(attrs.get("interrupted", False)),
        "score": assessment.score,
        "max_score": assessment.max_score,
        "metrics": assessment.metrics,
        "competency": {name: list(level) for name, level in assessment.competency.items()},
        "questionnaire": read_questionnaire(session),
    }
    with _CACHE_LOCK:
        _CACHE[path.resolve()] = (key, summary)
    return summary


def session_files(sources: list[Path]) -> list[Path]:
    """The session files named, and those in the folders named (``*.h5``), in start order (their names)."""
    files: list[Path] = []
    for source in sources:
        if source.is_dir():
            files += sorted(source.glob("*.h5"))
        elif source.is_file():
            files.append(source)
        else:
            raise ThrsimInputError(f"{source}: no such session file or folder")
    return sorted(dict.fromkeys(files), key=lambda p: p.name)


def summaries(files: list[Path], skip_unreadable: bool = False, thresholds: Thresholds | None = None) -> list[dict]:
    """Every file's summary scored against ``thresholds``, oldest first; an unreadable file raises, or
    with ``skip_unreadable`` is listed as ``{"session": stem, "error": why}``."""
    rows = []
    for path in files:
        try:
            rows.append(summarise(path, thresholds))
        except ThrsimInputError as error:
            if not skip_unreadable:
                raise
            rows.append({"session": path.stem, "error": str(error)})
    return sorted((r for r in rows if "error" not in r), key=lambda r: r["started_utc"]) + [r for r in rows if "error" in r]


def of_trainee(rows: list[dict], trainee: str) -> list[dict]:
    """The sessions of one trainee (names compared ignoring case and surrounding spaces), oldest first."""
    wanted = trainee.strip().casefold()
    return [r for r in rows if "error" not in r and r["trainee"].strip().casefold() == wanted]


def metric_names(rows: list[dict]) -> list[str]:
    """Every metric any of the rows has, in the order first met."""
    return list(dict.fromkeys(name for r in rows if "error" not in r for name in r["metrics"]))


def competency(rows: list[dict]) -> dict[str, list]:
    """Metric → [threshold, "max" or "min"]: the competency levels the rows' reports state."""
    return {name: level for r in rows if "error" not in r for name, level in r["competency"].items()}


def _flat(row: dict, metrics: list[str]) -> dict:
    answers = (row["questionnaire"] or {}).get("answers", {})
    flat = {column: row[column] for column in COLUMNS}
    flat |= {name: row["metrics"].get(name) for name in metrics}
    flat |= {f"q_{item}": answers.get(item) for item in ITEMS}
    flat["q_comment"] = (row["questionnaire"] or {}).get("comment")
    return flat


def _cell(value: object) -> object:
    """A CSV cell: empty where absent; text that a spreadsheet would run as a formula (``= + - @``)
    is kept as text by a leading apostrophe (a trainee's comment is free text)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, str) and value[:1] in ("=", "+", "-", "@"):
        return "'" + value
    return value


def to_csv(rows: list[dict]) -> str:
    """One row per session: the :data:`COLUMNS`, every metric, then each questionnaire item (``q_``); empty where absent."""
    rows = [r for r in rows if "error" not in r]
    metrics = metric_names(rows)
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=[*COLUMNS, *metrics, *(f"q_{item}" for item in ITEMS), "q_comment"], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _cell(v) for k, v in _flat(row, metrics).items()})
    return out.getvalue()


def _finite(value):
    """``value`` with every non-finite float made None (JSON has no NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def to_json(rows: list[dict]) -> dict:
    """``{"sessions": [...], "competency": {...}, "questionnaire_items": {...}}``: each session's summary
    as data (None where a value was not measured)."""
    rows = [r for r in rows if "error" not in r]
    return _finite(
        {
            "sessions": [{k: v for k, v in r.items() if k != "competency"} for r in rows],
            "competency": competency(rows),
            "questionnaire_items": ITEMS,
        }
    )
