"""Shared output of the benchmark scripts: a markdown table, a CSV file and a book page
(and the ``--only`` selection of the cases, which decides whether the page is written).

Imported by the scripts in this folder (``python benchmarks/<script>.py`` puts the
folder on ``sys.path``). Call on rank 0 only.

A full run (no ``--quick``, ``--small`` or ``--only``) also writes the script's page
of the book, ``docs/benchmarks/<script>.md``: every table it printed, each with the
command that produced it, the date and the machine, and appends a line to the book's
log of reruns, ``docs/benchmarks/reruns.md``. Tables that an earlier run of another
part of the script wrote stay on the page; a table that no part writes any more goes
with the page (delete it and rerun every part). The pages are never edited by hand.
``ADMM_BENCHMARK_PAGE=0`` turns this off (the smoke run of ``make test`` does).
"""

from __future__ import annotations

import atexit
import csv
import datetime
import os
import platform
import sys
from collections.abc import Sequence
from pathlib import Path

from admm_dolfinx.io.output import atomic_file

#: The book's log of full benchmark runs, one line per run, next to the pages.
RERUNS = "reruns.md"
RERUNS_HEADER = (
    "# Benchmark reruns\n\n"
    "Each full run of a benchmark script that rewrites its page of the book adds a line\n"
    "here (`benchmarks/tables.py`); the page itself carries the command, date and machine\n"
    "of each of its tables. Do not edit by hand.\n\n"
)


def markdown_table(rows: Sequence[dict]) -> str:
    """The rows as a markdown table; columns are the union of keys, first seen first."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]

    def cell(value: object) -> str:  # a "|" inside a cell would split it
        return str(value).replace("|", "\\|")

    lines = ["| " + " | ".join(cell(k) for k in keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(cell(row.get(k, "–")) for k in keys) + " |" for row in rows]
    return "\n".join(lines)


ROOT = Path(__file__).resolve().parents[1]
PAGES = ROOT / "docs" / "benchmarks"
_PARTIAL_RUN = ("--quick", "--small", "--only")
_tables: list[tuple[str, str]] = []


def select(parser, cases: dict, only: str | None) -> dict:
    """The cases named in ``--only`` (comma-separated), in that order, or all of them;
    an unknown name is a usage error naming the known ones."""
    if not only:
        return cases
    wanted = only.split(",")
    unknown = [name for name in wanted if name not in cases]
    if unknown:
        parser.error(f"--only: unknown cases {unknown}; there are {list(cases)}")
    return {name: cases[name] for name in wanted}


def _page_wanted() -> bool:
    if os.environ.get("ADMM_BENCHMARK_PAGE", "1") == "0":
        return False
    return not any(arg.split("=")[0] in _PARTIAL_RUN for arg in sys.argv[1:])


def _script() -> Path:
    return Path(sys.argv[0]).resolve()


def _provenance(command: str, stamp: str, machine: str) -> str:
    return f"Written by `{command}` on {stamp} ({machine})."


_SECTION = "\x00"  # marks the section headings found after the docstring block


def _existing_sections(page: Path) -> dict[str, str]:
    """The sections of an existing page, in order, each with its provenance.

    A section is ``## name`` and its body, after the script's docstring (whose fenced
    block may hold any line). Each body starts with the provenance line of the run that
    wrote it; a body from a page written before sections carried their own (one
    provenance line at the top of the page) gets that page's line.
    """
    if not page.exists():
        return {}
    text = page.read_text()
    fence = text.find("\n```\n", text.find("```text"))  # the docstring block's end
    split = fence + len("\n```\n") if fence >= 0 else 0
    head, *sections = (text[:split] + text[split:].replace("\n## ", _SECTION)).split(_SECTION)
    inherited = next((line for line in head.splitlines() if line.startswith("Written by `")), None)
    if inherited is not None and not inherited.endswith(")."):
        inherited = inherited.split("); ")[0] + ")."
    kept = {}
    for section in sections:
        name, _, body = section.partition("\n")
        body = body.strip("\n")
        if inherited is not None and not body.startswith("Written by `"):
            body = f"{inherited}\n\n{body}"
        kept[name] = body
    return kept


def _write_page() -> None:
    """The script's book page with the tables of this run (atexit; rank 0).

    Tables of other runs of the script (``--part rule`` and ``--part calibrate``, say)
    stay on the page, each with the command that wrote it.
    """
    # a script that died of an uncaught exception (sys.last_exc / last_type set by the
    # interpreter) or called sys.exit with an error writes no page
    if not _tables or getattr(sys, "last_type", None) is not None:
        return
    script = _script()
    main = sys.modules.get("__main__")
    doc = (getattr(main, "__doc__", None) or script.stem).strip()
    title = doc.splitlines()[0].rstrip(".")
    command = " ".join(["python", f"benchmarks/{script.name}", *sys.argv[1:]])
    size = os.environ.get("PMI_SIZE") or os.environ.get("OMPI_COMM_WORLD_SIZE") or "1"
    if size != "1":
        command = f"mpiexec -n {size} {command}"
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    page = PAGES / f"{script.stem}.md"
    written = [name for name, _ in _tables]
    sections = _existing_sections(page)  # a rewritten table keeps its place
    provenance = _provenance(command, stamp, machine)
    for name, table in _tables:
        sections[name] = f"{provenance}\n\n{table}"
    lines = [
        f"# {title}",
        "",
        "Each table names the command that wrote it; do not edit by hand: rerun the",
        "command to refresh it.",
        "",
        "```text",
        doc,
        "```",
    ]
    for name, body in sections.items():
        lines += ["", f"## {name}", "", body]
    PAGES.mkdir(parents=True, exist_ok=True)
    with atomic_file(page) as fh:
        fh.write("\n".join(lines) + "\n")
    reruns = PAGES / RERUNS
    if not reruns.exists():
        reruns.write_text(RERUNS_HEADER)
    with reruns.open("a") as fh:
        tables = ", ".join(written)
        fh.write(f"- {stamp}: `{command}` wrote {tables} in docs/benchmarks/{script.stem}.md\n")


def print_and_save(rows: Sequence[dict], path: Path) -> None:
    """Print the markdown table and write the CSV whole (temporary file, then rename).

    On a full run the table also goes to the script's book page (see the module).
    """
    if not rows:
        return
    table = markdown_table(rows)
    print(table, flush=True)
    if _page_wanted():
        if not _tables:
            atexit.register(_write_page)
        name = Path(path).stem.replace("_", " ")
        # a table saved again as it grows (a script's progress) keeps its last version
        _tables[:] = [(n, t) for n, t in _tables if n != name]
        _tables.append((name, table))
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with atomic_file(path, newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys, restval="–")
        writer.writeheader()
        writer.writerows(rows)
