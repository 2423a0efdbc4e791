"""``thrsim review``: the thesis's simulator review rubric, its reviewed simulators, and thrsim."""

from __future__ import annotations

import typer
from rich.table import Table

from thrsim.cli.output import console, print_json

_SHORT = {"met": "○", "partial": "∩", "not met": "-"}


def review(json_out: bool = typer.Option(False, "--json", help="print one JSON object")) -> None:
    """Score simulators on the thesis's nine criteria (a–i, three groups of 0–5), thrsim included."""
    from thrsim.review import review as build

    result = build()
    if json_out:
        print_json(result)
        return
    table = Table(title="Simulator review (thesis 2.2.1, Tables 2–3): ○ met, ∩ partial, - not met")
    table.add_column("simulator")
    for letter in result["criteria"]:
        table.add_column(letter, justify="center")
    for group in result["groups"]:
        table.add_column(group.split()[0] + f" ({'–'.join(result['groups'][group][::2])})", justify="right")
    rows = [(name, entry) for name, entry in result["simulators"].items()] + [("thrsim (today)", result["thrsim"])]
    for name, entry in rows:
        table.add_row(name, *(_SHORT[m] for m in entry["marks"].values()), *(str(s) for s in entry["scores"].values()))
    console.print(table)
    for letter, text in result["criteria"].items():
        console.print(f"{letter}. {text} — thrsim: {result['thrsim']['marks'][letter]} ({result['thrsim']['reasons'][letter]})")
