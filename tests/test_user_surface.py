"""What a new user reaches for is where they look for it."""

import admm_dolfinx
from admm_dolfinx import ADMMSolver
from admm_dolfinx.scenes.library import example1


def test_the_readme_names_are_importable_from_the_top_level():
    """LinearElastic and ContactWriter are used in the README: no submodule needed."""
    from admm_dolfinx.io.paraview import ContactWriter
    from admm_dolfinx.problem.material import LinearElastic

    assert admm_dolfinx.LinearElastic is LinearElastic
    assert admm_dolfinx.ContactWriter is ContactWriter
    assert {"LinearElastic", "ContactWriter", "solve_adaptive"} <= set(admm_dolfinx.__all__)


def test_printing_a_result_is_one_line():
    problem = example1(h=1 / 8).problem()
    with ADMMSolver(problem) as solver:
        result = solver.solve()
    text = repr(result)
    assert "\n" not in text and len(text) < 200
    assert "status='converged'" in text and f"iterations={result.iterations}" in text
    assert str(result) == text
