"""What a new user reaches for is where they look for it."""

import admm_dolfinx
from admm_dolfinx import ADMMSolver
from admm_dolfinx.scenes.library import example1


def test_the_readme_names_are_importable_from_the_top_level():
    """LinearElastic and ContactWriter are used in the README: no submodule needed."""
    from admm_dolfinx.io.paraview import ContactWriter
    from admm_dolfinx.scenes.material import LinearElastic

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


class _Terminal:
    """A stand-in for a terminal's stderr."""

    def __init__(self):
        self.lines = []

    def isatty(self):
        return True

    def write(self, text):
        self.lines.append(text)

    def flush(self):
        pass


def _progress_lines(monkeypatch, configure):
    import logging
    import sys

    import admm_dolfinx.admm.iteration as iteration_module

    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(iteration_module, "PROGRESS_SECONDS", 0.0)
    root, package = logging.getLogger(), logging.getLogger("admm_dolfinx")
    monkeypatch.setattr(root, "handlers", [])  # a plain script: nothing configured
    monkeypatch.setattr(package, "level", logging.NOTSET)
    configure(monkeypatch)
    with ADMMSolver(example1(h=1 / 8).problem()) as solver:
        result = solver.solve()
    return [t for t in terminal.lines if t.startswith("ADMM ")], result


def test_a_long_solve_shows_progress_in_a_terminal_without_logging_set_up(monkeypatch):
    from mpi4py import MPI

    lines, result = _progress_lines(monkeypatch, lambda m: None)
    assert len(lines) == (result.iterations if MPI.COMM_WORLD.rank == 0 else 0)


def test_the_progress_lines_can_be_turned_off(monkeypatch):
    import logging

    off = [
        lambda m: m.setenv("ADMM_DOLFINX_PROGRESS", "0"),
        lambda m: m.setattr(logging.getLogger("admm_dolfinx"), "level", logging.WARNING),
    ]
    for configure in off:
        lines, _ = _progress_lines(monkeypatch, configure)
        assert lines == []
