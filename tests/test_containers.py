"""The Dockerfiles run exactly the Makefile targets that CI runs natively.

Docker cannot run here, so this test is what keeps the images honest: every RUN/CMD
step that installs or reproduces is a `make` target of the Makefile, `make test` (CI)
runs `venv` and the same `reproduce` recipe (with `--quick`), and `make -n` accepts
the targets with the variables the Dockerfiles pass.
"""

import json
import re
import shlex
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILES = {
    "Dockerfile.dolfinx": "ghcr.io/fenics/dolfinx/dolfinx:v0.11.0",
    "Dockerfile.wheel": "python:3.12-slim",
}


def makefile_rules() -> dict[str, tuple[list[str], list[str]]]:
    """target -> (prerequisites, recipe lines)."""
    rules: dict[str, tuple[list[str], list[str]]] = {}
    current = None
    for line in (ROOT / "Makefile").read_text().splitlines():
        match = re.match(r"^([\w./$()-]+):(?!=)\s*(.*)$", line)
        if match and not line.startswith("\t"):
            current = match.group(1)
            rules[current] = (match.group(2).split(), [])
        elif line.startswith("\t") and current:
            rules[current][1].append(line.strip())
        elif not line.strip():
            current = None
    return rules


def make_invocations(dockerfile: Path) -> list[list[str]]:
    """The argument lists of every `make` call in RUN and CMD instructions."""
    calls = []
    for line in dockerfile.read_text().splitlines():
        if line.startswith("RUN ") and "make " in line and "apt-get" not in line:
            calls.append(shlex.split(line[4:]))
        elif line.startswith("CMD "):
            calls.append(json.loads(line[4:]))
    return [c for c in calls if c and c[0] == "make"]


@pytest.mark.parametrize("name", sorted(DOCKERFILES))
def test_dockerfile_uses_ci_make_targets(name):
    dockerfile = ROOT / "containers" / name
    text = dockerfile.read_text()
    assert f"FROM {DOCKERFILES[name]}" in text
    calls = make_invocations(dockerfile)
    targets = [c[1] for c in calls]
    assert targets == ["venv", "reproduce"], targets
    rules = makefile_rules()
    for call in calls:
        assert call[1] in rules
        variables = [a for a in call[2:] if "=" in a]
        dry = subprocess.run(
            ["make", "-n", "-C", str(ROOT), call[1], *variables, "VENV=/nonexistent-venv"],
            capture_output=True,
            text=True,
        )
        assert dry.returncode == 0, dry.stderr
        if call[1] == "venv":
            extras = dict(v.split("=", 1) for v in variables).get("EXTRAS")
            expected = f'-e ".[{extras}]"' if extras else '-e ".[fenics'
            assert expected in dry.stdout


def test_ci_runs_the_same_install_and_reproduce_recipes():
    rules = makefile_rules()
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^make test$", ci, re.M), ".ci/run must call the README's `make test`"
    assert "make test" in (ROOT / "README.md").read_text()
    assert "reproduce-quick" in rules["test"][0]
    assert "venv" in rules["test-serial"][0]
    (full,) = rules["reproduce"][1]
    (quick,) = rules["reproduce-quick"][1]
    assert quick == full.replace("reproduce all", "reproduce all --quick").replace(
        "$(OUT)", "$(OUT)_quick"
    )
