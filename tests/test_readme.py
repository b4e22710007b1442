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
