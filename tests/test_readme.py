"""The README describes what a user of this repository can run: the paths it names exist and
the commands it names are thrsim's."""

from __future__ import annotations

import re

from checkout_cli import REPO_ROOT

README = (REPO_ROOT / "README.md").read_text()


def test_every_path_the_readme_names_exists():
    paths = set(re.findall(r"`((?:thrsim|tests)/[\w./-]*)`", README))
    assert paths, "the README names no paths"
    missing = sorted(p for p in paths if not (REPO_ROOT / p).exists())
    assert not missing, missing


def test_every_command_the_readme_names_is_a_thrsim_command():
    import typer

    from thrsim.cli import app

    group = typer.main.get_command(app)
    # inline code (`thrsim dataset info DIR`) and command lines in code blocks
    named = set(re.findall(r"`thrsim ([a-z]+)(?: ([a-z]+))?", README))
    named |= set(re.findall(r"^(?:\s{4,}|)thrsim ([a-z]+)(?: ([a-z]+))?", README, flags=re.MULTILINE))
    assert {"mesh", "fem", "dataset", "track", "nav", "verify"} <= {c for c, _ in named}
    for command, sub in named:
        assert command in group.commands, f"thrsim {command}"
        inner = group.commands[command]
        if sub and getattr(inner, "commands", None):
            assert sub in inner.commands, f"thrsim {command} {sub}"


def test_no_citation_of_files_this_repository_does_not_hold():
    for name in ("NOTES", "SPEC"):
        assert not re.search(rf"\b{name}\b", README), name


def test_no_code_cites_files_this_repository_does_not_hold():
    """A reader has only this repository: code states the fact (with the thesis as citation)."""
    citing = re.compile(r"\b(?:NOTES|SPEC)\b")
    offenders = [
        f"{path.relative_to(REPO_ROOT)}:{number}"
        for path in sorted([*(REPO_ROOT / "thrsim").rglob("*.py"), *(REPO_ROOT / "tests").rglob("*.py")])
        if path.name != "test_readme.py"
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if citing.search(line)
    ]
    assert not offenders, offenders
