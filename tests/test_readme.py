"""The README's FEniCS-workflow examples run as written (serially and under MPI)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _run_blocks(*names: str) -> dict:
    """Execute the README's tested blocks ``<!-- readme-NAME -->`` in one namespace."""
    text = README.read_text()
    namespace: dict = {}
    for name in names:
        match = re.search(rf"<!-- readme-{name} -->\s*```python\n(.*?)```", text, re.S)
        assert match, f"README.md lost its tested block readme-{name}"
        exec(compile(match.group(1), "README.md", "exec"), namespace)
    return namespace


def test_readme_example_runs(capsys):
    result = _run_blocks("example")["result"]
    assert result.converged and result.num_active > 0
    assert result.kkt.max() < 1e-3  # default rtol = 1e-5: KKT residuals ~1e-4
    assert result.pressure.x.array.min() >= 0.0


def test_readme_load_steps_run():
    """The load-step block, after the example (tests/admm/test_load_steps.py checks that no
    step refactorises and that each matches a problem assembled afresh)."""
    first = _run_blocks("example")["result"]
    result = _run_blocks("example", "load-steps")["result"]
    assert result.converged and result.kkt.max() < 1e-3
    assert result.num_active > first.num_active  # heavier, and the floor is higher


def test_readme_union_obstacle():
    """The user-defined obstacle of the README: two planes, the nearest wins."""
    import numpy as np

    import admm_dolfinx

    union = _run_blocks("union")["Union"](
        admm_dolfinx.Plane((0.0, 0.0), (0.0, 1.0)), admm_dolfinx.Plane((0.0, -1.0), (1.0, 1.0))
    )
    g, nu = union.signed_distance(np.array([[0.0, 0.5], [-3.0, 1.0]]))
    np.testing.assert_allclose(g, [0.5, (-3.0 + 2.0) / np.sqrt(2.0)])
    np.testing.assert_allclose(nu, [[0.0, 1.0], [np.sqrt(0.5), np.sqrt(0.5)]])


def test_readme_names_what_it_promises():
    """What it points to exists."""
    text = README.read_text()
    root = README.parent
    for path in ("LICENSE", "CITATION.cff", "docs/index.md", "containers", "demos/load_steps.py"):
        assert (root / path).exists(), path
    assert "hal-02047516" in text


def test_the_readme_settings_table_is_the_user_surface():
    """The README's settings table lists exactly the settings a user sets by name, in
    order, with the defaults that ``ADMMSettings.create()`` gives."""
    import re

    from admm_dolfinx import ADMMSettings
    from admm_dolfinx.admm.settings import PAPER_RTOL, USER_SETTINGS

    section = README.read_text().split("## Settings", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(\w+)` \| (.+?) \|", section, flags=re.MULTILINE)
    assert [name for name, _ in rows] == list(USER_SETTINGS)
    defaults, stated = ADMMSettings.create(), dict(rows)
    assert stated["penalty"] == f'`"{defaults.penalty}"`'
    assert stated["mode"] == f'`"{defaults.mode}"`'
    assert stated["rtol"] == f"`{defaults.rtol:.0e}` (paper: `{PAPER_RTOL:.0e}`)".replace(
        "e-0", "e-"
    )
    assert stated["max_iter"] == f"`{defaults.max_iter}`"
    assert defaults.polish is None and stated["polish"] == "automatic"
    assert stated["step1"] == f'`"{defaults.step1}"`'
    assert dict(defaults.petsc_options) == {} and stated["petsc_options"] == "`{}`"
    assert stated["petsc_options_prefix"] == f'`"{defaults.petsc_options_prefix}"`'
