"""Shared output of the benchmark scripts: a markdown table on stdout and a CSV file.

Imported by the scripts in this folder (``python benchmarks/<script>.py`` puts the
folder on ``sys.path``). Call on rank 0 only.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

from admm_dolfinx.io.output import atomic_file


def markdown_table(rows: Sequence[dict]) -> str:
    """The rows as a markdown table; columns are the union of keys, first seen first."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(str(row.get(k, "–")) for k in keys) + " |" for row in rows]
    return "\n".join(lines)


def print_and_save(rows: Sequence[dict], path: Path) -> None:
    """Print the markdown table and write the CSV whole (temporary file, then rename)."""
    if not rows:
        return
    print(markdown_table(rows), flush=True)
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with atomic_file(path, newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys, restval="–")
        writer.writeheader()
        writer.writerows(rows)
