"""``thrsim verify``: run the explicit solver's verification checks and report them.

Exit code 0 when every check run passes, 1 when any fails (2 for a usage error such as an
unknown ``--only`` name). ``--json`` prints one JSON object: ``passed``, ``seconds``,
``include_slow``, ``skipped_slow`` (slow families not run) and ``checks``, a list of records
with name, check (family), figure, reference, value, error, tolerance, passed, seconds, slow,
units and details.
"""

from __future__ import annotations

import time

import typer
from rich.console import JustifyMethod
from rich.table import Table

from thrsim.cli.output import console, err_console, print_json
from thrsim.errors import ThrsimInputError

#: the table's columns and how each is aligned
_COLUMNS: tuple[tuple[str, JustifyMethod], ...] = (
    ("check", "left"), ("value", "right"), ("reference", "right"), ("error", "right"),
    ("tolerance", "right"), ("units", "left"), ("s", "right"), ("", "center"),
)  # fmt: skip


def _number(value: float | None) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return str(value)
    return f"{value:.5g}"


def verify(
    slow: bool = typer.Option(False, "--slow", help="include the slow checks (a short reaming case)"),
    only: list[str] | None = typer.Option(
        None, "--only", help="run only this check family or figure (repeatable, or comma-separated)", metavar="NAME"
    ),
    list_checks: bool = typer.Option(False, "--list", help="list the checks and their figures, run nothing"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object on stdout"),
) -> None:
    """Verify the explicit solver: closed forms, conservation, convergence and a CalculiX cross-check."""
    from thrsim.verification import registry, run_checks, select

    names = [n.strip() for item in (only or []) for n in item.split(",") if n.strip()]
    if list_checks:
        checks = registry()
        if as_json:
            print_json(
                {
                    "checks": [
                        {"name": c.name, "description": c.description, "slow": c.slow, "figures": list(c.figures)} for c in checks.values()
                    ]
                }
            )
        else:
            table = Table(title="verification checks")
            for column in ("check", "slow", "figures", "description"):
                table.add_column(column)
            for c in checks.values():
                table.add_row(c.name, "yes" if c.slow else "", "\n".join(c.figures), c.description)
            console.print(table)
        return
    try:
        selected = select(names or None, include_slow=slow)
    except KeyError as error:
        raise ThrsimInputError(str(error.args[0])) from None
    skipped = [] if names or slow else [c.name for c in registry().values() if c.slow]

    started = time.perf_counter()
    if as_json:
        results = run_checks(names or None, include_slow=slow)
    else:
        with console.status("verifying") as status:
            results = run_checks(names or None, include_slow=slow, progress=lambda c: status.update(f"verifying: {c.name}"))
    seconds = time.perf_counter() - started
    passed = all(r.passed for r in results) and bool(results)

    if as_json:
        print_json({
            "passed": passed,
            "seconds": seconds,
            "include_slow": slow,
            "families": [c.name for c, _ in selected],
            "skipped_slow": skipped,
            "checks": [r.as_dict() for r in results],
        })  # fmt: skip
    else:
        table = Table(title="thrsim verification")
        for column, justify in _COLUMNS:
            table.add_column(
                column, justify=justify, no_wrap=column != "check", overflow="fold", min_width=24 if column == "check" else None
            )
        for r in results:
            mark = "[green]pass[/green]" if r.passed else "[bold red]FAIL[/bold red]"
            table.add_row(r.name + (" (slow)" if r.slow else ""), _number(r.value), _number(r.reference), _number(r.error),
                          _number(r.tolerance), r.units, f"{r.seconds:.2f}", mark)  # fmt: skip
        console.print(table)
        failed = [r.name for r in results if not r.passed]
        summary = f"{len(results) - len(failed)}/{len(results)} passed in {seconds:.1f} s"
        if skipped:
            summary += f"; slow checks not run (use --slow): {', '.join(skipped)}"
        console.print(summary)
        for r in results:
            console.print(f"[dim]{r.name}: {r.figure}[/dim]", highlight=False)
        for r in results:
            if not r.passed and "exception" in r.details:
                err_console.print(f"{r.name}: {r.details['exception']}")
    if not passed:
        raise typer.Exit(1)
