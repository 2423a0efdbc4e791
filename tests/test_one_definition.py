"""One definition of each thing: the defaults live in thrsim.config, the trained ranges in the model
card, the page takes its own from the server, one Side and one mirror, the server names no mode, the
report's parts import no circle, the library's errors name settings (the CLI names the flags), and
nothing is defined that the package never uses."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from collections import Counter
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "thrsim"
STATIC = PACKAGE / "app" / "static"
#: the solver's own modules keep their numbers: they are outside these checks
OUTSIDE = ("physics", "geometry")


def _modules(skip: tuple[str, ...] = ()) -> list[Path]:
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE)
        if relative.parts[0] in OUTSIDE or relative.parts[0] in skip or relative.as_posix() == "config.py":
            continue
        found.append(path)
    return found


def _numbers(path: Path):
    tokens = list(tokenize.generate_tokens(io.StringIO(path.read_text()).readline))
    for k, token in enumerate(tokens):
        if token.type == tokenize.NUMBER and not token.string.lower().startswith(("0x", "0o", "0b")):
            yield float(token.string.replace("_", "").rstrip("jJ")), tokens[max(0, k - 2) : k], token


def test_the_frame_rate_and_the_push_are_defined_once_in_config():
    found = []
    for path in _modules():
        for value, before, token in _numbers(path):
            where = f"{path.relative_to(PACKAGE)}:{token.start[0]}: {token.line.strip()}"
            if value == 230.0:
                found.append(where)  # the push: config.PUSH_FORCE_N
            elif value == 60.0 and (
                re.search(r"hz|fps|frame_dt|tick", token.line, re.IGNORECASE)
                or ([t.string for t in before][-1:] == ["/"] and before[0].type == tokenize.NUMBER)
            ):
                found.append(where)  # the frame rate: config.FRAME_RATE_HZ
    for path in _modules():
        for line, text in _strings(path):
            if re.search(r"\b230\b|\b60\s*Hz|\b60 per\b|1/60", text):
                found.append(f"{path.relative_to(PACKAGE)}:{line}: {text!r}")  # a help text or label: format config's value in
    assert not found, "a second definition of 60 Hz or 230 N (use thrsim.config's):\n" + "\n".join(found)


def _docstring_ids(tree: ast.AST) -> set[int]:
    """ids of the docstring constants of a parsed module, its classes and functions."""
    return {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }


def _strings(path: Path):
    """(line, text) of every string literal but docstrings (prose may say what the thesis's defaults are)."""
    tree = ast.parse(path.read_text())
    docstrings = _docstring_ids(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            yield node.lineno, node.value


def test_the_page_takes_its_defaults_from_the_server():
    for page in STATIC.glob("*.js"):
        text = page.read_text()
        assert not re.search(r"\b230\b", text), f"{page.name}: a push of its own (the hello's defaults.force_n)"
        assert not re.search(r"(inclination|anteversion)_deg:\s*-?\d", text), (
            f"{page.name}: an aim of its own (the hello's defaults.reamer)"
        )


def test_the_server_and_the_pages_start_from_the_same_aim():
    from thrsim.app.reaming import ReamingTrainer
    from thrsim.config import PUSH_FORCE_N, SafeZone

    trainer = ReamingTrainer()
    defaults = trainer.defaults()
    zone = SafeZone()
    assert defaults["reamer"] == {"inclination_deg": zone.inclination_deg, "anteversion_deg": zone.anteversion_deg}
    assert defaults["force_n"] == PUSH_FORCE_N == trainer.page_force_n
    angles = trainer.step(0.0)["angles"]["radiographic"]  # the trainer's reamer is where the page's starts
    assert angles == pytest.approx([zone.inclination_deg, zone.anteversion_deg])


def test_the_trained_ranges_are_read_from_the_model_card():
    """The push (150–310 N) and aim (γ ≤ 45°) the shipped model learned are its card's
    (``LoadedModel.trained_force_n``, ``trained_inclination_deg``): the trainer, its page, the
    sessions and the report hold no copy, so a model trained on other ranges is judged by its own."""
    found = []
    for path in _modules():
        if path.relative_to(PACKAGE).parts[0] not in ("app", "report", "session"):
            continue
        for value, _, token in _numbers(path):
            line = token.line
            if (value in (150.0, 310.0) and re.search(r"(?i:force|push|_n\b)|\bN\b", line)) or (
                value == 45.0 and re.search(r"trained|learn|γ|gamma|inclination", line, re.IGNORECASE)
            ):
                found.append(f"{path.relative_to(PACKAGE)}:{token.start[0]}: {line.strip()}")
    for page in [*STATIC.glob("*.js"), *STATIC.glob("*.html")]:
        for number, line in enumerate(page.read_text().splitlines(), 1):
            if re.search(r"\b(150|310)\b", line) and re.search(r"(?i:force|push)|\bN\b", line):
                found.append(f"{page.name}:{number}: {line.strip()}")
            if re.search(r"\b45\b", line) and re.search(r"trained|learn|γ|gamma|inclination", line, re.IGNORECASE):
                found.append(f"{page.name}:{number}: {line.strip()}")
    assert not found, "a trained range of its own (read the model card's):\n" + "\n".join(found)


def _raised_texts(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            for inner in ast.walk(node.exc):
                if isinstance(inner, ast.Constant) and isinstance(inner.value, str):
                    yield node.lineno, inner.value


def test_library_errors_name_settings_not_command_line_flags():
    found = [
        f"{path.relative_to(PACKAGE)}:{line}: {text!r}"
        for path in _modules(skip=("cli",))
        for line, text in _raised_texts(path)
        if re.search(r"(^|[\s(`])--[a-z]", text)
    ]
    assert not found, "library errors that name a flag (name the setting: ThrsimInputError(message, setting)):\n" + "\n".join(found)


def test_the_cli_words_a_setting_as_its_flag():
    from thrsim.cli.output import user_message
    from thrsim.errors import ThrsimInputError

    error = ThrsimInputError(
        "admits trackers from other machines: give the address to listen on as well (igtl_host)", "igtl_allow", ("igtl_host",)
    )
    assert str(error).startswith("igtl_allow: admits")
    assert user_message(error) == "--igtl-allow: admits trackers from other machines: give the address to listen on as well (--igtl-host)"
    assert user_message(ThrsimInputError("must lie in [0, 90] degrees, got 95", "inclination_deg")).startswith("--inclination: ")


def test_one_side_type_and_one_mirror():
    """``Side`` is thrsim.config's; the left hip's mirror is thrsim.nav.bone_frame's (geometry's meshes mirror themselves)."""
    sides, mirrors = [], []
    for path in _modules():
        text = path.read_text()
        where = path.relative_to(PACKAGE).as_posix()
        if re.search(r"Literal\[\s*\"(right|left)\",\s*\"(right|left)\"\s*\]", text):
            sides.append(where)
        if re.search(r"\[\s*-1(\.0)?,\s*1(\.0)?,\s*1(\.0)?\s*\]", text) and where != "nav/bone_frame.py":
            mirrors.append(where)
    assert not sides, f"a second Side type (use thrsim.config.Side): {sides}"
    assert not mirrors, f"a mirror of its own (use thrsim.nav.bone_frame.on_side): {mirrors}"


def test_the_generic_server_names_no_mode():
    """Routes, streams, settings and health figures of one mode are its Mode hooks (thrsim.app.modes)."""
    from thrsim.app.modes import MODES

    tree = ast.parse((PACKAGE / "app" / "server.py").read_text())
    docstrings = _docstring_ids(tree)
    named = [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
        if re.search(rf"\b({'|'.join(MODES)})\b", node.value)
    ]
    assert not named, f"the server names a mode: {named}"
    reached = {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)}
    assert not reached & {"simulator", "levels", "frames_run"}, "the server reaches into a mode's trainer"


def test_the_report_assembly_and_its_sections_import_no_circle():
    """The sections build on thrsim.report.parts; only the assembly (document) reaches the sections, through the modes."""
    for section in ("navigation", "reaming", "parts"):
        tree = ast.parse((PACKAGE / "report" / f"{section}.py").read_text())
        imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
        imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
        assert not {"thrsim.report", "thrsim.report.document"} & imported, f"report/{section}.py imports the assembly"


#: top-level functions and classes the package itself does not use, and why they stay
USED_OUTSIDE_THE_PACKAGE = {
    "io/igtl.py": {
        "unpack_string": "the peer's side of the codec: decodes the NavigationState the server sends",
        "unpack_status": "the peer's side of the codec: decodes the server's STATUS replies",
    },
    "geometry/tet_metrics.py": {"volume_quality": "the solver's folder: its owner decides"},
}


def test_every_top_level_function_and_class_is_used_by_the_package():
    """Code nothing calls is removed (as the OpenIGTLink reamer hook and a dataset class only tests
    used were), or listed above with the reason it stays. Decorated definitions are registered by
    their decorator (routes, commands, validators) and count as used."""
    sources = {path: path.read_text() for path in sorted(PACKAGE.rglob("*.py"))}
    words = Counter(re.findall(r"\w+", "\n".join(sources.values())))
    unused = []
    for path, source in sources.items():
        where = path.relative_to(PACKAGE).as_posix()
        for node in ast.parse(source).body:
            if (
                isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                and not node.decorator_list
                and not node.name.startswith("__")
            ):
                if words[node.name] <= 1 and node.name not in USED_OUTSIDE_THE_PACKAGE.get(where, {}):
                    unused.append(f"{where}:{node.lineno}: {node.name}")
    assert not unused, "defined and never used by thrsim (remove it, or say above why it stays):\n" + "\n".join(unused)
    for where, names in USED_OUTSIDE_THE_PACKAGE.items():
        for name in names:
            assert words[name] == 1, f"{where}: {name} is used now or gone: drop it from the list"
