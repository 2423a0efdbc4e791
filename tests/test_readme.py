"""The README and the documentation pages describe what a user of this repository can run: the
paths they name exist, the commands they name are thrsim's, and the README's command table
is the command's own list."""

from __future__ import annotations

import re

import pytest
from checkout_cli import REPO_ROOT, run_thrsim

README = (REPO_ROOT / "README.md").read_text()
DOC_PAGES = sorted(p for p in (REPO_ROOT / "docs").rglob("*.md") if "_hooks" not in p.parts)
DOCUMENTS = {"README.md": README} | {str(p.relative_to(REPO_ROOT)): p.read_text() for p in DOC_PAGES}


def _named_commands(text: str) -> set[tuple[str, str]]:
    """(command, subcommand or '') for inline code (`thrsim dataset info DIR`) and command lines
    in code blocks (fenced, or indented four spaces)."""
    named = set(re.findall(r"`thrsim ([a-z]+)(?: ([a-z]+))?", text))
    code = "\n".join(re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL))
    code += "\n" + "\n".join(re.findall(r"^ {4,}(thrsim .*)$", text, flags=re.MULTILINE))
    named |= set(re.findall(r"^\s*thrsim ([a-z]+)(?: ([a-z]+))?", code, flags=re.MULTILINE))
    return named


def _command_table(text: str) -> list[str]:
    """The README's command table: each row's `thrsim ...` command, in order."""
    section = text.split("\n## Commands\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `thrsim ([a-z ]+)` \|", section, flags=re.MULTILINE)


def _listed_commands(*group: str) -> set[str]:
    """The commands `thrsim [GROUP] --help` lists (its Commands panel)."""
    result = run_thrsim(*group, "--help", env={"COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"})
    assert result.returncode == 0, result.stderr
    panel = result.stdout.split("Commands", 1)[1]
    return set(re.findall(r"^\W*([a-z][a-z-]*)\s{2,}\S", panel, flags=re.MULTILINE))


def test_the_readme_is_short():
    assert len(README.splitlines()) <= 250


def test_every_path_the_readme_and_the_docs_name_exists():
    for name, text in DOCUMENTS.items():
        paths = set(re.findall(r"`((?:thrsim|tests|docs|datasets)/[\w./-]*)`", text))
        if name == "README.md":
            assert paths, "the README names no paths"
        missing = sorted(p for p in paths if not (REPO_ROOT / p).exists())
        assert not missing, (name, missing)


def test_every_file_the_readme_links_exists():
    links = re.findall(r"\]\(((?!https?:|#)[^)\s#]+)", README)
    assert any(link.startswith("docs/") and link.endswith(".png") for link in links), "the README shows no pictures"
    missing = sorted(link for link in links if not (REPO_ROOT / link).exists())
    assert not missing, missing


def test_every_command_the_readme_and_the_docs_name_is_a_thrsim_command():
    import typer

    from thrsim.cli import app

    group = typer.main.get_command(app)
    readme_named = _named_commands(README)
    assert {"serve", "ream", "mesh", "fem", "dataset", "track", "nav", "verify"} <= {c for c, _ in readme_named}
    for name, text in DOCUMENTS.items():
        for command, sub in _named_commands(text):
            assert command in group.commands, f"{name}: thrsim {command}"
            inner = group.commands[command]
            if sub and getattr(inner, "commands", None):
                assert sub in inner.commands, f"{name}: thrsim {command} {sub}"


def test_the_readme_command_table_is_what_thrsim_help_lists():
    """Every row names a command `python3 -m thrsim --help` (or its group's --help) lists, and
    every command listed there has its row: the table cannot fall behind the command."""
    rows = _command_table(README)
    assert rows, "the README has no command table"
    top = _listed_commands()
    assert {"serve", "ream", "train", "dataset", "nav"} <= top, top
    groups = {row.split()[0] for row in rows if len(row.split()) > 1}
    sub = {group: _listed_commands(group) for group in groups}
    for row in rows:
        command, *rest = row.split()
        assert command in top, f"thrsim {row}: not in `thrsim --help`"
        if rest:
            assert rest[0] in sub[command], f"thrsim {row}: not in `thrsim {command} --help`"
    assert top <= {row.split()[0] for row in rows}, sorted(top - {row.split()[0] for row in rows})
    for group, listed in sub.items():
        tabled = {row.split()[1] for row in rows if row.startswith(group + " ") and len(row.split()) > 1}
        assert listed <= tabled, (group, sorted(listed - tabled))


@pytest.mark.parametrize("name", ["NOTES", "SPEC"])
def test_no_citation_of_files_this_repository_does_not_hold(name):
    documents = {**DOCUMENTS, "mkdocs.yml": (REPO_ROOT / "mkdocs.yml").read_text()}
    offenders = [doc for doc, text in documents.items() if re.search(rf"\b{name}\b", text)]
    assert not offenders, offenders


def test_no_code_cites_files_this_repository_does_not_hold():
    """A reader has only this repository: code states the fact (with the thesis as citation)."""
    citing = re.compile(r"\b(?:NOTES|SPEC)\b")
    offenders = [
        f"{path.relative_to(REPO_ROOT)}:{number}"
        for path in sorted(
            [*(REPO_ROOT / "thrsim").rglob("*.py"), *(REPO_ROOT / "tests").rglob("*.py"), *(REPO_ROOT / "docs").rglob("*.py")]
        )
        if path.name != "test_readme.py"
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if citing.search(line)
    ]
    assert not offenders, offenders


def test_the_quick_start_installs_serves_the_trainer_reams_and_tests():
    quick = README.split("\n## Quick start\n", 1)[1].split("\n## ", 1)[0]
    steps = ["./install.sh", "thrsim serve", "http://127.0.0.1:8000/", "thrsim ream", "python3 -m pytest"]
    at = [quick.find(step) for step in steps]
    assert -1 not in at and at == sorted(at), dict(zip(steps, at, strict=True))  # in the order a newcomer takes them
