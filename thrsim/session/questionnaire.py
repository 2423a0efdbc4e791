"""The optional post-session questionnaire: Likert items answered after a session ends, stored in its file.

In the manner of the thesis's face-validation study [3.4], trainees rate statements (thrsim's
wording) about the realism of the bone, the forces and the instruments and the trainer's
usefulness for training, each from 1 (strongly disagree) to 5 (strongly agree). Every item is
optional; a comment may go with them.

Group ``/questionnaire`` of the session file: attrs ``answers`` (JSON object, item → 1–5),
``comment`` and ``answered_utc``. The file is rewritten whole, to a temporary name that is then
renamed (:mod:`thrsim.atomic`); answering again replaces the earlier answers.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
from pathlib import Path

import h5py

from thrsim.atomic import atomic_path
from thrsim.errors import ThrsimInputError
from thrsim.session.file import SessionFile, read_session

GROUP = "questionnaire"
#: item → the statement a trainee rates
ITEMS: dict[str, str] = {
    "bone_realism": "The bone looked and behaved like real bone.",
    "force_realism": "The resistance felt while reaming was realistic.",
    "instrument_realism": "The reamer and the probe moved like the real instruments.",
    "navigation_usefulness": "The navigation display helped me orient the cup.",
    "training_usefulness": "The trainer is useful for learning acetabular reaming.",
    "would_recommend": "I would recommend the trainer to other trainees.",
}
SCALE = {1: "strongly disagree", 2: "disagree", 3: "neutral", 4: "agree", 5: "strongly agree"}
MAX_COMMENT = 1000


def check_answers(answers: object, comment: object = "") -> tuple[dict[str, int], str]:
    """The answers and comment as stored; ThrsimInputError (one line) for an unknown item, a rating
    outside 1–5, a comment too long or not text, or nothing answered at all."""
    if not isinstance(answers, dict):
        raise ThrsimInputError("answers must be an object of item: rating (1–5)")
    unknown = [str(k)[:40] for k in answers if k not in ITEMS]
    if unknown:
        raise ThrsimInputError(f"unknown questionnaire item {unknown[0]!r}; known: {', '.join(ITEMS)}")
    for item, rating in answers.items():
        if type(rating) is not int or rating not in SCALE:
            raise ThrsimInputError(f"{item}: a rating is a whole number from 1 to 5, not {str(rating)[:20]!r}")
    if not isinstance(comment, str) or len(comment) > MAX_COMMENT:
        raise ThrsimInputError(f"the comment must be text of at most {MAX_COMMENT} characters")
    comment = " ".join(comment.split())  # one line: it goes into a CSV cell
    if not answers and not comment:
        raise ThrsimInputError("nothing answered: rate at least one item or leave a comment")
    return {item: answers[item] for item in ITEMS if item in answers}, comment


def write_questionnaire(path: str | Path, answers: object, comment: object = "") -> dict:
    """Store the answers in the session file at ``path`` (checked first: nothing is written when they
    are refused); returns what was stored."""
    path = Path(path)
    read_session(path)  # a session file this thrsim reads, or one line saying why not
    answers, comment = check_answers(answers, comment)
    stored = {"answers": answers, "comment": comment, "answered_utc": dt.datetime.now(dt.UTC).isoformat()}
    with atomic_path(path) as tmp:
        shutil.copyfile(path, tmp)
        with h5py.File(tmp, "r+") as h5:
            if GROUP in h5:
                del h5[GROUP]
            group = h5.create_group(GROUP)
            group.attrs.update(answers=json.dumps(answers), comment=comment, answered_utc=stored["answered_utc"])
    return stored


def read_questionnaire(session: SessionFile) -> dict | None:
    """The stored answers of a session read back (None when it has none)."""
    group = session.groups.get(GROUP)
    if group is None:
        return None
    attrs = {k: v.decode() if isinstance(v, bytes) else v for k, v in group["attrs"].items()}
    try:
        answers, comment = check_answers(json.loads(attrs.get("answers", "{}")), str(attrs.get("comment", "")))
    except (ValueError, ThrsimInputError) as error:
        raise ThrsimInputError(f"{session.path}: garbled questionnaire ({error})") from None
    return {"answers": answers, "comment": comment, "answered_utc": str(attrs.get("answered_utc", ""))}
