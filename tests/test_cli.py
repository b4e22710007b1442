"""The command line and the output writers."""

import json
import logging

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx.cli import main
from admm_dolfinx.io.output import output_folder, write_json


def _shared_tmp(tmp_path_factory, name):
    path = tmp_path_factory.mktemp(name) if MPI.COMM_WORLD.rank == 0 else None
    return MPI.COMM_WORLD.bcast(path, root=0)


def test_run_writes_json_and_xdmf(tmp_path_factory):
    tmp = _shared_tmp(tmp_path_factory, "run")
    status = main(
        [
            "run",
            "example1",
            "--h",
            "0.125",
            "--json",
            str(tmp / "s.json"),
            "--out",
            str(tmp / "out"),
        ]
    )
    assert status == 0
    data = json.loads((tmp / "s.json").read_text())
    assert data["converged"] and data["iterations"] > 0 and data["contact_nodes"] == 16
    assert data["processes"] == MPI.COMM_WORLD.size
    assert (tmp / "out" / "solution.xdmf").exists() and (tmp / "out" / "solution.h5").exists()


def test_run_reports_non_convergence(tmp_path_factory):
    tmp = _shared_tmp(tmp_path_factory, "fail")
    status = main(
        [
            "run",
            "example1",
            "--h",
            "0.125",
            "--max-iter",
            "2",
            "--no-polish",
            "--json",
            str(tmp / "s.json"),
        ]
    )
    assert status == 2
    assert json.loads((tmp / "s.json").read_text())["converged"] is False


@pytest.mark.parametrize("metric", ["auto", "mass"])
def test_run_3d_penalty_metric(tmp_path_factory, metric):
    tmp = _shared_tmp(tmp_path_factory, f"metric_{metric}")
    argv = ["run", "example3", "--level", "0", "--penalty-metric", metric]
    assert main([*argv, "--json", str(tmp / "s.json")]) == 0
    data = json.loads((tmp / "s.json").read_text())
    assert data["converged"]
    assert data["plan"].endswith(")") and ("metric surface" in data["plan"]) == (metric == "auto")


def test_run_polish_on_request_in_3d(tmp_path_factory):
    tmp = _shared_tmp(tmp_path_factory, "polish")
    argv = ["run", "example3", "--level", "0", "--polish", "--json", str(tmp / "s.json")]
    assert main(argv) == 0
    data = json.loads((tmp / "s.json").read_text())
    assert "polish dense" in data["plan"] and data["converged"]
    assert max(data["kkt"].values()) <= 1e-10  # polished: exact, not merely at rtol


def test_output_folder_writes_nothing_on_failure(tmp_path_factory):
    tmp = _shared_tmp(tmp_path_factory, "atomic")
    target = tmp / "result"
    with pytest.raises(RuntimeError), output_folder(MPI.COMM_WORLD, target) as folder:
        (folder / f"part{MPI.COMM_WORLD.rank}.txt").write_text("half")
        raise RuntimeError("interrupted")
    MPI.COMM_WORLD.Barrier()
    assert list(target.iterdir()) == []  # the folder is created up front, left empty


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "run" in out and "reproduce" in out


def test_unwritable_output_is_a_clear_error_on_every_rank(tmp_path_factory):
    """An output path that rank 0 cannot create (here: below a regular file) raises
    the same OSError on every rank, naming the path, instead of leaving the other
    ranks waiting; nothing is written."""
    tmp = _shared_tmp(tmp_path_factory, "unwritable")
    blocker = tmp / "a_file"
    if MPI.COMM_WORLD.rank == 0:
        blocker.write_text("not a folder")
    MPI.COMM_WORLD.Barrier()
    with pytest.raises(OSError, match=r"a_file/out.*writable"):
        with output_folder(MPI.COMM_WORLD, blocker / "out"):
            pass
    with pytest.raises(OSError, match=r"a_file/s\.json.*writable"):
        write_json(MPI.COMM_WORLD, blocker / "s.json", {"a": 1})
    MPI.COMM_WORLD.Barrier()
    assert sorted(p.name for p in tmp.iterdir()) == ["a_file"]


def test_output_folder_fails_on_every_rank_when_one_rank_fails(tmp_path_factory):
    """A block that fails on one rank only: every rank raises that error (so that none
    goes on to wait at a later collective call); nothing is written."""
    tmp = _shared_tmp(tmp_path_factory, "one_rank")
    target = tmp / "result"
    last = MPI.COMM_WORLD.size - 1
    with pytest.raises(ValueError, match="plot failed"):
        with output_folder(MPI.COMM_WORLD, target) as folder:
            (folder / f"part{MPI.COMM_WORLD.rank}.txt").write_text("whole")
            if MPI.COMM_WORLD.rank == last:
                raise ValueError("this rank's plot failed")
    MPI.COMM_WORLD.Barrier()
    assert list(target.iterdir()) == []


def test_cli_unwritable_output_is_an_error_message(tmp_path_factory, capsys):
    """The command line reports an unwritable --out as one line and exit status 1, on
    every rank (no traceback, no rank left waiting)."""
    tmp = _shared_tmp(tmp_path_factory, "cli_out")
    blocker = tmp / "a_file"
    if MPI.COMM_WORLD.rank == 0:
        blocker.write_text("not a folder")
    MPI.COMM_WORLD.Barrier()
    status = main(["run", "example1", "--h", "0.25", "--json", str(blocker / "s.json")])
    assert status == 1
    if MPI.COMM_WORLD.rank == 0:
        err = capsys.readouterr().err
        assert "admm-dolfinx: error: Cannot write the output" in err and "a_file" in err


def test_a_figure_that_fails_on_rank_0_fails_on_every_rank(tmp_path_factory, monkeypatch):
    """Rank 0 draws alone: a renderer error there (planted) is raised on every rank by
    the plot itself, before any rank moves on to another collective call."""
    import admm_dolfinx.io.plotting as plotting

    def broken():
        raise ValueError("no renderer")

    monkeypatch.setattr(plotting, "_pyplot", broken)
    tmp = _shared_tmp(tmp_path_factory, "figure")
    with pytest.raises(RuntimeError, match="failed on rank 0: ValueError: no renderer"):
        plotting.plot_iterations_vs_penalty(
            [("mesh", np.array([1.0, 2.0]), np.array([3, 4]))], tmp / "f.png"
        )
    MPI.COMM_WORLD.Barrier()
    assert list(tmp.iterdir()) == []


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["run", "example1", "--h", "-1"], "h must be a positive finite length"),
        (["run", "example1", "--h", "0.25", "--penalty", "-5"], "penalty r must be a positive"),
        (["run", "example1", "--level", "2"], "example1's mesh is set by --h"),
        (["run", "example2", "--h", "0.1"], "example2's is set by --level"),
    ],
)
def test_cli_bad_input_is_an_error_message(argv, message, capsys):
    """Bad input on the command line: the library's message on one line, status 1."""
    assert main(argv) == 1
    if MPI.COMM_WORLD.rank == 0:
        assert message in capsys.readouterr().err


def test_version(capsys):
    import admm_dolfinx

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"admm-dolfinx {admm_dolfinx.__version__}"


@pytest.mark.parametrize(
    ("argv", "verbose"),
    [
        (["-v", "run", "example1"], True),
        (["run", "example1", "-v"], True),
        (["run", "-v", "example1", "--h", "0.5"], True),
        (["reproduce", "all", "--verbose"], True),
        (["run", "example1"], False),
    ],
)
def test_verbose_anywhere_on_the_command_line(argv, verbose):
    from admm_dolfinx.cli import build_parser

    assert build_parser().parse_args(argv).verbose is verbose


def test_missing_plotting_extra_is_one_line_and_the_rest_is_written(tmp_path_factory, monkeypatch):
    import warnings

    import admm_dolfinx
    from admm_dolfinx.scenes.library import example1
    from admm_dolfinx.studies import report

    monkeypatch.setattr(report, "available", lambda name: name != "pyvista")
    tmp = _shared_tmp(tmp_path_factory, "noplot")
    scene = example1(h=0.25)
    problem = scene.problem()
    result = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix="noplot_").solve()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report.write_scene_outputs(tmp / "out", scene, problem, result)
    MPI.COMM_WORLD.barrier()
    names = sorted(p.name for p in (tmp / "out").iterdir())
    assert names == ["solution.h5", "solution.xdmf", "summary.json"]
    if MPI.COMM_WORLD.rank == 0:
        lines = [str(w.message) for w in caught if "No figures" in str(w.message)]
        assert len(lines) == 1 and "pip install pyvista" in lines[0]
        assert "'.[plot]'" in lines[0]


def test_a_missing_extra_names_both_ways_to_install_it():
    from admm_dolfinx._extras import require

    with pytest.raises(ImportError, match=r"pip install gmsh.*\.\[scenes\]") as info:
        import admm_dolfinx._extras as extras

        extras.EXTRAS["no_such_module_xyz"] = ("gmsh", "scenes")
        try:
            require("no_such_module_xyz", "The scenes build their meshes with gmsh")
        finally:
            del extras.EXTRAS["no_such_module_xyz"]
    assert "The scenes build their meshes with gmsh" in str(info.value)


def test_the_figure_moves_the_obstacle_with_the_magnified_body():
    """The active nodes of Example 1 touch the plane 0.01 below: their mean displacement
    is the gap, so the magnified picture draws the plane that much further down."""
    import admm_dolfinx
    from admm_dolfinx.scenes.library import example1
    from admm_dolfinx.studies.report import _contact_displacement

    problem = example1(h=0.125).problem()
    result = admm_dolfinx.ADMMSolver(problem, petsc_options_prefix="shift_").solve()
    shift = _contact_displacement(problem, result)
    gap = problem.contact.gap[result.multiplier > 0]
    gaps = np.concatenate(MPI.COMM_WORLD.allgather(gap))
    assert shift[1] == pytest.approx(-gaps.mean(), rel=1e-6)


@pytest.fixture
def package_log(caplog):
    """Records of the package's log; its level is reset afterwards (main() sets it)."""
    yield caplog
    logging.getLogger("admm_dolfinx").setLevel(logging.NOTSET)


def _messages(caplog, level):
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == level and r.name.startswith("admm_dolfinx")
    ]


@pytest.mark.parametrize("verbose", [False, True])
def test_run_logs_stages_and_each_iteration_only_with_verbose(package_log, verbose):
    """`run` shows its stages (plan, r*, step 1) by default; -v adds every iteration."""
    with package_log.at_level(logging.DEBUG):
        status = main(["run", "example1", "--h", "0.125", *(["-v"] if verbose else [])])
    assert status == 0
    if MPI.COMM_WORLD.rank != 0:  # the package logs on rank 0 only
        assert not _messages(package_log, logging.INFO)
        return
    info = _messages(package_log, logging.INFO)
    assert any(m.startswith("ADMM: ") and "contact nodes" in m for m in info)
    assert any(m.startswith("r* = ") and "dense pencil" in m for m in info)  # not "0 solves"
    iterations = [m for m in _messages(package_log, logging.DEBUG) if m.startswith("ADMM    1:")]
    assert len(iterations) == (1 if verbose else 0)


def test_reproduce_logs_nothing_but_its_own_progress(package_log, tmp_path_factory):
    """`reproduce` prints its own progress; the solves under it do not log their stages."""
    tmp = _shared_tmp(tmp_path_factory, "reproduce")
    with package_log.at_level(logging.DEBUG):
        main(["reproduce", "table2", "--quick", "--out", str(tmp)])
    assert not _messages(package_log, logging.INFO)


def test_a_long_solve_reports_progress(package_log, monkeypatch):
    """A progress line at INFO every PROGRESS_SECONDS (here every iteration)."""
    import admm_dolfinx.admm.iteration as iteration_module
    from admm_dolfinx import ADMMSolver
    from admm_dolfinx.scenes import example1

    monkeypatch.setattr(iteration_module, "PROGRESS_SECONDS", 0.0)
    logging.getLogger("admm_dolfinx").setLevel(logging.INFO)
    with package_log.at_level(logging.INFO), ADMMSolver(example1(h=0.125).problem()) as s:
        result = s.solve()
    lines = [
        m for m in _messages(package_log, logging.INFO) if m.startswith("ADMM ") and "fpr" in m
    ]
    assert len(lines) == (result.iterations if MPI.COMM_WORLD.rank == 0 else 0)


def test_run_help_describes_every_scene(capsys):
    from admm_dolfinx.scenes.library import SCENES

    with pytest.raises(SystemExit):
        main(["run", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for name in SCENES:
        assert f"{name} (" in out, name


@pytest.mark.parametrize(
    ("argv", "hint"),
    [
        (["run", "example2", "--levle", "1"], "--levle: did you mean --level?"),
        (["run", "example1", "--rtoll=1e-8"], "--rtoll: did you mean --rtol?"),
        (["reproduce", "table1", "--quik"], "--quik: did you mean --quick?"),
    ],
)
def test_a_mistyped_option_names_the_closest_one(argv, hint, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert hint in capsys.readouterr().err


def test_an_unknown_option_far_from_any_gets_no_hint(capsys):
    with pytest.raises(SystemExit):
        main(["run", "example1", "--zzzz"])
    err = capsys.readouterr().err
    assert "unrecognized arguments: --zzzz" in err and "did you mean" not in err
