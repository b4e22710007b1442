"""The README's FEniCS-workflow example runs as written (serially and under MPI)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_example_runs(capsys):
    text = README.read_text()
    match = re.search(r"<!-- readme-example -->\s*```python\n(.*?)```", text, re.S)
    assert match, "README.md lost its tested example block"
    namespace: dict = {}
    exec(compile(match.group(1), "README.md", "exec"), namespace)
    result = namespace["result"]
    assert result.converged and result.num_active > 0
    assert result.kkt.max() < 1e-3  # default rtol = 1e-5: KKT residuals ~1e-4
    assert namespace["result"].pressure.x.array.min() >= 0.0


def test_readme_load_steps_run():
    """The load-step block, after the example (tests/test_load_steps.py checks that no
    step refactorises and that each matches a problem assembled afresh)."""
    text = README.read_text()
    blocks = [
        re.search(rf"<!-- readme-{name} -->\s*```python\n(.*?)```", text, re.S)
        for name in ("example", "load-steps")
    ]
    assert all(blocks), "README.md lost a tested example block"
    namespace: dict = {}
    exec(compile(blocks[0].group(1), "README.md", "exec"), namespace)
    first = namespace["result"]
    exec(compile(blocks[1].group(1), "README.md", "exec"), namespace)
    result = namespace["result"]
    assert result.converged and result.kkt.max() < 1e-3
    assert result.num_active > first.num_active  # heavier, and the floor is higher
