"""MkDocs hook: the command reference is generated from the ``thrsim`` command itself.

``docs/commands.md`` holds the markers ``<!-- thrsim: command reference -->`` and
``<!-- /thrsim: command reference -->``; at build time what lies between them (a note for
readers of the plain Markdown file) is replaced by every command and subcommand of this checkout's ``thrsim`` (its usage line, its help
text and each option with the help and default that ``thrsim CMD --help`` prints). So the page
cannot fall behind the code: a new command or option appears on the next build, and a page
without the marker fails the build.
"""

from __future__ import annotations

import sys
from pathlib import Path

MARKER = "<!-- thrsim: command reference -->"
END_MARKER = "<!-- /thrsim: command reference -->"
PAGE = "commands.md"
REPO_ROOT = Path(__file__).resolve().parents[2]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _command_markdown(command, ctx, path: list[str], level: int) -> list[str]:
    """Markdown for one command (and, for a group, its subcommands after it)."""
    name = " ".join(path)
    lines = [f"{'#' * level} `{name}`", ""]
    if command.help:
        lines += [command.help.strip(), ""]
    usage = command.get_usage(ctx).replace("Usage: ", "", 1).strip()
    lines += ["```text", usage, "```", ""]
    rows = []
    for param in command.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is None or record[0].startswith("--help"):
            continue  # hidden options, and --help (every command has it)
        option, help_text = record
        rows.append(f"| `{_cell(option)}` | {_cell(help_text)} |")
    if rows:
        lines += ["| option | meaning |", "|---|---|", *rows, ""]
    subcommands = getattr(command, "commands", None) or {}
    for sub_name in command.list_commands(ctx) if subcommands else []:
        sub = subcommands[sub_name]
        sub_ctx = sub.context_class(sub, info_name=sub_name, parent=ctx)
        lines += _command_markdown(sub, sub_ctx, [*path, sub_name], level + 1)
    return lines


def command_reference() -> str:
    """The whole reference: one section per ``thrsim`` command, in the order ``thrsim --help`` lists them."""
    if str(REPO_ROOT) not in sys.path:
        sys.path.insert(0, str(REPO_ROOT))  # this checkout's thrsim, whatever is installed
    import typer

    from thrsim.cli import app

    group = typer.main.get_command(app)
    root = group.context_class(group, info_name="thrsim")
    lines: list[str] = []
    for name in group.list_commands(root):
        command = group.commands[name]
        ctx = command.context_class(command, info_name=name, parent=root)
        lines += _command_markdown(command, ctx, ["thrsim", name], 2)
    return "\n".join(lines)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri != PAGE:
        return markdown
    if MARKER not in markdown or END_MARKER not in markdown.split(MARKER, 1)[1]:
        raise ValueError(f"{PAGE} lost its markers {MARKER!r} … {END_MARKER!r}: the command reference would not be generated")
    before, rest = markdown.split(MARKER, 1)
    after = rest.split(END_MARKER, 1)[1]
    return before + command_reference() + after
