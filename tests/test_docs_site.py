"""The documentation site (MkDocs, `mkdocs.yml`): every page in its navigation exists, every page
is in it, CI builds it strictly, and the command reference is generated from every command.

The full build (`python3 -m mkdocs build --strict`, links and anchors included) runs in
`.ci/run`; these checks are the cheap, precise ones."""

from __future__ import annotations

import importlib.util
import re
import tomllib

import yaml
from checkout_cli import REPO_ROOT

DOCS = REPO_ROOT / "docs"
CONFIG = yaml.safe_load((REPO_ROOT / "mkdocs.yml").read_text())


def _nav_pages(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, list):
        return [page for item in node for page in _nav_pages(item)]
    if isinstance(node, dict):
        return [page for value in node.values() for page in _nav_pages(value)]
    return []


def _hook():
    spec = importlib.util.spec_from_file_location("cli_reference", DOCS / "_hooks" / "cli_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_page_in_the_nav_exists():
    pages = [p for p in _nav_pages(CONFIG["nav"]) if not p.startswith(("http://", "https://"))]
    assert len(pages) >= 10, pages
    missing = [p for p in pages if not (DOCS / p).is_file()]
    assert not missing, missing
    assert len(pages) == len(set(pages)), "a page is in the nav twice"


def test_every_page_is_in_the_nav():
    pages = set(_nav_pages(CONFIG["nav"]))
    written = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md") if "_hooks" not in p.parts}
    assert written <= pages, sorted(written - pages)


def test_the_pages_the_project_promises_are_there():
    pages = set(_nav_pages(CONFIG["nav"]))
    for page in ("index.md", "trainer.md", "tracker.md", "commands.md", "physics.md", "learned-simulator.md",
                 "data-formats.md", "benchmarks.md", "security.md", "contributing.md"):  # fmt: skip
        assert page in pages, page
    for package in ("geometry", "physics", "data", "learn", "render", "nav", "io", "app", "session", "report"):
        page = DOCS / "api" / f"{package}.md"
        assert page.is_file() and f"::: thrsim.{package}" in page.read_text(), page


def test_every_package_and_top_level_module_has_its_api_reference():
    """A package added to thrsim gets its page, a top-level module its entry: the API reference
    cannot silently leave code out (each page documents its package's submodules itself)."""
    package = REPO_ROOT / "thrsim"
    pages = set(_nav_pages(CONFIG["nav"]))
    for sub in sorted(p for p in package.iterdir() if (p / "__init__.py").is_file()):
        page = f"api/{sub.name}.md"
        assert page in pages and f"::: thrsim.{sub.name}" in (DOCS / page).read_text(), page
    top = (DOCS / "api" / "thrsim.md").read_text()
    for module in sorted(p.stem for p in package.glob("*.py") if p.stem not in ("__init__", "__main__")):
        assert f"::: thrsim.{module}\n" in top + "\n", module


def test_the_site_is_material_with_mkdocstrings_and_its_hook():
    assert CONFIG["theme"]["name"] == "material"
    plugins = [next(iter(p)) if isinstance(p, dict) else p for p in CONFIG["plugins"]]
    assert "mkdocstrings" in plugins and "search" in plugins
    for hook in CONFIG["hooks"]:
        assert (REPO_ROOT / hook).is_file(), hook


def test_ci_builds_the_site_strictly_between_install_and_tests():
    lines = [line.strip() for line in (REPO_ROOT / ".ci" / "run").read_text().splitlines()]
    install = next(i for i, line in enumerate(lines) if line.startswith("./install.sh"))
    build = next(i for i, line in enumerate(lines) if "mkdocs build" in line)
    tests = next(i for i, line in enumerate(lines) if line.startswith("python3 -m pytest"))
    assert install < build < tests
    assert "--strict" in lines[build]


def test_the_docs_tools_are_in_the_dev_extra():
    dev = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    names = {re.split(r"[<>=!~ ]", requirement, maxsplit=1)[0] for requirement in dev}
    assert {"mkdocs", "mkdocs-material", "mkdocstrings[python]"} <= names, names


def test_the_command_reference_covers_every_command_and_option():
    import typer

    from thrsim.cli import app

    hook = _hook()
    page = (DOCS / "commands.md").read_text()
    assert hook.MARKER in page and hook.END_MARKER in page
    reference = hook.command_reference()
    group = typer.main.get_command(app)
    for name, command in group.commands.items():
        assert f"`thrsim {name}`" in reference, name
        for sub in getattr(command, "commands", {}) or {}:
            assert f"`thrsim {name} {sub}`" in reference, f"{name} {sub}"
    for option in ("--inclination", "--igtl-port", "--token", "--no-compile", "--element-sizes", "--json"):
        assert option in reference, option


#: a module's docstring says what the module is for and why in a few lines; formats, rules and
#: protocols go to the docstrings of the classes and functions that keep them, measurements and
#: history to the documentation pages (benchmarks.md above all)
MODULE_DOCSTRING_LINES = 12


def test_every_module_docstring_is_a_few_lines():
    import ast

    package = REPO_ROOT / "thrsim"
    lines = {
        path.relative_to(package).as_posix(): len((ast.get_docstring(ast.parse(path.read_text()), clean=False) or "").splitlines())
        for path in sorted(package.rglob("*.py"))
    }
    long = [f"thrsim/{name}: {count} lines" for name, count in lines.items() if count > MODULE_DOCSTRING_LINES]
    assert not long, f"module docstrings over {MODULE_DOCSTRING_LINES} lines (move the detail, see above):\n" + "\n".join(long)


def test_the_contributor_guide_names_the_examples_to_follow():
    """The parts to copy: the pure network beside the learned simulator, kernels with no I/O and named
    state, the model directory, the trainer protocol with exact replay, errors mapped at the edge."""
    guide = (DOCS / "contributing.md").read_text()
    patterns = guide.split("\n## Patterns to follow\n", 1)[1].split("\n## ", 1)[0]
    for heading in ("pure network", "no I/O", "model directory", "exact replay", "exit codes at the edge"):
        assert re.search(rf"^### .*{re.escape(heading)}", patterns, flags=re.MULTILINE | re.IGNORECASE), heading
    named = set(re.findall(r"`(thrsim/[\w/]+\.py)`", patterns))
    assert {"thrsim/learn/network.py", "thrsim/learn/model_dir.py", "thrsim/app/replay.py", "thrsim/cli/__init__.py"} <= named, named
    assert all((REPO_ROOT / path).is_file() for path in named), sorted(p for p in named if not (REPO_ROOT / p).is_file())


def test_the_tracker_page_names_every_device_and_the_port_the_trainer_uses():
    from thrsim.config import KNOWN_TRACKER_DEVICES, IgtlConfig

    page = (DOCS / "tracker.md").read_text()
    missing = [device for device in KNOWN_TRACKER_DEVICES if f"`{device}`" not in page]
    assert not missing, f"tracker.md does not name these device names: {missing}"
    assert str(IgtlConfig().port) in page and "PLUS" in page and "3D Slicer" in page
    from thrsim.io import feedback

    sent = (feedback.EVENT_DEVICE, feedback.SIM_REAMER_DEVICE, feedback.REACTION_DEVICE, feedback.TORQUE_DEVICE)
    assert not [device for device in sent if f"`{device}`" not in page], "tracker.md does not name what thrsim sends back"
