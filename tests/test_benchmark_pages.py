"""A benchmark run writes its tables to the script's book page without dropping others.

``benchmarks/tables.py`` writes ``docs/benchmarks/<script>.md``. A script with parts
(``--part rule``, ``--part calibrate``) runs them one at a time; each run must replace
its own tables and keep the rest, each table with the command that wrote it.
"""

import importlib.util
import sys
from pathlib import Path

import pytest

TABLES = Path(__file__).resolve().parents[1] / "benchmarks" / "tables.py"


@pytest.fixture
def tables(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("benchmark_tables", TABLES)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "ROOT", tmp_path)
    monkeypatch.setattr(module, "PAGES", tmp_path / "pages")
    monkeypatch.setattr(module, "_script", lambda: tmp_path / "demo_bench.py")
    for name in ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE"):  # the command as a serial run's
        monkeypatch.delenv(name, raising=False)
    return module


def _run(tables, monkeypatch, argv, named_tables):
    monkeypatch.setattr(sys, "argv", ["demo_bench.py", *argv])
    tables._tables[:] = named_tables
    tables._write_page()


def test_parts_keep_each_others_tables(tables, monkeypatch, tmp_path):
    page = tmp_path / "pages" / "demo_bench.md"
    _run(tables, monkeypatch, ["--part", "rule"], [("bench rule", "| a |\n|---|\n| 1 |")])
    _run(tables, monkeypatch, ["--part", "cal"], [("bench cal", "| b |\n|---|\n| 2 |")])
    text = page.read_text()
    rule, cal = text.split("\n## bench rule\n")[1].split("\n## bench cal\n")
    assert "`python benchmarks/demo_bench.py --part rule`" in rule and "| 1 |" in rule
    assert "`python benchmarks/demo_bench.py --part cal`" in cal and "| 2 |" in cal
    assert "--part cal" not in rule and "--part rule" not in cal
    # the rule part again: its table is replaced in place, the other one kept
    _run(tables, monkeypatch, ["--part", "rule"], [("bench rule", "| a |\n|---|\n| 3 |")])
    text = page.read_text()
    assert text.index("## bench rule") < text.index("## bench cal")
    assert "| 1 |" not in text and "| 3 |" in text and "| 2 |" in text
    assert text.count("## bench rule") == 1
    log = (tmp_path / "pages" / "reruns.md").read_text().splitlines()
    assert log[0] == "# Benchmark reruns"
    assert sum(line.startswith("- ") for line in log) == 3
    assert log[-1].endswith("wrote bench rule in docs/benchmarks/demo_bench.md")


def test_a_page_of_the_old_layout_keeps_its_provenance(tables, monkeypatch, tmp_path):
    """A page written with one provenance line at its top, before tables carried their own."""
    page = tmp_path / "pages" / "demo_bench.md"
    page.parent.mkdir()
    page.write_text(
        "# Demo\n\nWritten by `python benchmarks/demo_bench.py --part cal` on 2026-01-01 "
        "00:00 UTC (x86_64, 2 cores, Python 3.12.1); do not edit by hand: rerun the\n"
        "command to refresh it.\n\n```text\nDemo.\n```\n\n## bench cal\n\n| b |\n|---|\n| 2 |\n"
    )
    _run(tables, monkeypatch, ["--part", "rule"], [("bench rule", "| a |\n|---|\n| 1 |")])
    cal = page.read_text().split("\n## bench cal\n")[1].split("\n## ")[0]
    assert cal.strip().startswith(
        "Written by `python benchmarks/demo_bench.py --part cal` on 2026-01-01 00:00 UTC "
        "(x86_64, 2 cores, Python 3.12.1)."
    )
    assert "| 2 |" in cal


def test_a_heading_inside_the_scripts_docstring_is_not_a_table(tables, monkeypatch, tmp_path):
    page = tmp_path / "pages" / "demo_bench.md"
    monkeypatch.setattr(
        sys.modules["__main__"], "__doc__", "Demo.\n\n## not a table\n", raising=False
    )
    _run(tables, monkeypatch, ["--part", "rule"], [("bench rule", "| a |\n|---|\n| 1 |")])
    _run(tables, monkeypatch, ["--part", "cal"], [("bench cal", "| b |\n|---|\n| 2 |")])
    text = page.read_text()
    assert text.count("## not a table") == 1 and text.count("```") == 2
    assert text.index("## not a table") < text.index("```", text.index("```text") + 1)
