"""Command line: ``admm-dolfinx run <scene>`` and ``admm-dolfinx reproduce <table>``.

Every command works under ``mpirun -n N admm-dolfinx ...``; only rank 0 prints.
"""

from __future__ import annotations

import argparse
import difflib
import logging
import sys
import time
from pathlib import Path
from typing import NoReturn

from mpi4py import MPI

from admm_dolfinx.admm.solver import ADMMConvergenceError, ADMMSolver
from admm_dolfinx.io.output import check_output_folder, write_json
from admm_dolfinx.scenes.library import SCENES
from admm_dolfinx.studies.report import result_summary, write_scene_outputs
from admm_dolfinx.studies.reproduce import TABLES, run_table


def _say(*args) -> None:
    if MPI.COMM_WORLD.rank == 0:
        print(*args, flush=True)


def _penalty(text: str):
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"penalty must be 'auto' or a number, got {text!r}"
        ) from None


def _numbers(text: str) -> list[float]:
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers such as 0,0,-1, got {text!r}"
        ) from None
    return values


def _tagged_vector(text: str) -> tuple[int, list[float]]:
    tag, sep, vector = text.partition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected TAG:VECTOR such as 4:0,-0.01, got {text!r}")
    try:
        return int(tag), _numbers(vector)
    except ValueError:
        raise argparse.ArgumentTypeError(f"the tag of {text!r} is not an integer") from None


def _two_parts(text: str) -> tuple[list[float], list[float]]:
    first, sep, second = text.partition("/")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected A/B such as 0,0,0/0,0,1, got {text!r}")
    return _numbers(first), _numbers(second)


#: The options of ``run --mesh`` (the user's own mesh file).
_MESH_OPTIONS = ("contact", "fixed", "displace", "traction", "body_force", "plane", "ball")


def _scene_from_mesh_file(args):
    from admm_dolfinx.problem.obstacles import Ball, Plane
    from admm_dolfinx.scenes.from_file import scene_from_file

    if args.scene is not None or args.level is not None or args.h is not None:
        raise ValueError("--mesh runs your own mesh: give no scene name, --level or --h with it.")
    if args.contact is None:
        raise ValueError("--mesh needs --contact TAG: the tag of the facets that may touch.")
    if (args.plane is None) == (args.ball is None):
        raise ValueError(
            "--mesh needs one obstacle: --plane POINT/NORMAL (the normal from the obstacle "
            "towards the body, e.g. --plane 0,0,0/0,0,1) or --ball CENTRE/RADIUS."
        )
    if args.plane is not None:
        obstacle = Plane(*args.plane)
    else:
        centre, radius = args.ball
        if len(radius) != 1:
            raise ValueError(f"--ball takes CENTRE/RADIUS with one radius, got {radius}.")
        obstacle = Ball(centre, radius[0])
    return scene_from_file(
        args.mesh,
        contact=args.contact,
        obstacle=obstacle,
        fixed=args.fixed or (),
        displaced=dict(args.displace or ()),
        tractions=dict(args.traction or ()),
        body_force=args.body_force,
        E=args.E,
        nu=args.nu,
    )


def _build_scene(args):
    if args.mesh is not None:
        return _scene_from_mesh_file(args)
    given = [f"--{name.replace('_', '-')}" for name in _MESH_OPTIONS if getattr(args, name)]
    if given:
        raise ValueError(f"{', '.join(given)} go with --mesh FILE (your own mesh).")
    if args.scene is None:
        raise ValueError(
            f"run needs a scene ({', '.join(sorted(SCENES))}) or --mesh FILE (your own)."
        )
    if args.scene == "example1":
        if args.level is not None:
            raise ValueError(
                "--level sets the mesh of example2, example3, hertz and hertz_sphere; "
                "example1's mesh is set by --h (e.g. --h 0.015625)."
            )
        return SCENES["example1"](
            h=1 / 32 if args.h is None else args.h, mesher=args.mesher or "gmsh"
        )
    if args.h is not None or args.mesher is not None:
        raise ValueError(
            f"--h and --mesher set example1's mesh; {args.scene}'s is set by --level "
            "(each level halves the element size)."
        )
    return SCENES[args.scene](level=0 if args.level is None else args.level)


def cmd_run(args) -> int:
    """Solve one scene and report (optionally a JSON summary and XDMF output)."""
    comm = MPI.COMM_WORLD
    # the output locations are checked before the work, not after the solve
    if args.out:
        check_output_folder(comm, args.out)
    if args.json:
        check_output_folder(comm, Path(args.json).resolve().parent)
    scene = _build_scene(args)
    # the paper's algorithm runs in the paper's model (along the body's normal)
    problem = scene.problem(
        contact_normal=args.contact_normal or ("body" if args.mode == "paper" else "obstacle")
    )
    _say(
        f"{scene.name}: {scene.num_nodes} nodes, {problem.num_contact_nodes} contact nodes, "
        f"{comm.size} process(es)"
    )
    t0 = time.perf_counter()
    status = 0
    try:
        options = {
            "penalty": args.penalty,
            "mode": args.mode,
            "rtol": args.rtol,
            "max_iter": args.max_iter,
            "petsc_options_prefix": "run_",
        }
        if args.polish is not None:
            options["polish"] = args.polish
        if args.penalty_metric != "auto":
            options["expert"] = {"penalty_metric": args.penalty_metric}
        with ADMMSolver(problem, **options) as solver:
            result = solver.solve()
    except ADMMConvergenceError as err:
        result, status = err.result, 2
        _say(f"error: {err}")
    _say(result.summary())
    summary = result_summary(scene, problem, result) | {"wall_time": time.perf_counter() - t0}
    # the folder's set first: if it cannot be published whole, nothing is written
    if args.out:
        coordinate = "angle" if scene.name == "example2" else "x"
        write_scene_outputs(
            args.out,
            scene,
            problem,
            result,
            coordinate=coordinate,
        )
        _say(f"wrote {args.out}/")
    if args.json:
        write_json(comm, args.json, summary)
        _say(f"wrote {args.json}")
    problem.destroy()
    return status


def cmd_reproduce(args) -> int:
    """Regenerate one table, or all of them."""
    names = list(TABLES) if args.table == "all" else [args.table]
    t0 = time.perf_counter()
    for name in names:
        run_table(name, Path(args.out), quick=args.quick)
    _say(
        f"reproduce {args.table}: {time.perf_counter() - t0:.0f} s wall time; "
        f"CSV files in {args.out}/"
    )
    return 0


def _version() -> str:
    """The installed package's version."""
    from admm_dolfinx import __version__

    return __version__


_VERBOSE_HELP = "log every ADMM iteration (rank 0); without it `run` logs stages and progress"


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose error for an unknown option names the closest known one."""

    def error(self, message: str) -> NoReturn:
        if message.startswith("unrecognized arguments:"):
            known = _option_strings(self)
            hints = []
            for token in message.split(":", 1)[1].split():
                flag = token.split("=", 1)[0]
                if flag.startswith("-"):
                    close = difflib.get_close_matches(flag, known, n=1, cutoff=0.6)
                    if close:
                        hints.append(f"{flag}: did you mean {close[0]}?")
            if hints:
                message = f"{message} ({'; '.join(hints)})"
        super().error(message)


def _option_strings(parser: argparse.ArgumentParser) -> list[str]:
    """Every option string of ``parser`` and of its subcommands."""
    found: list[str] = []
    for action in parser._actions:
        found.extend(action.option_strings)
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                found.extend(_option_strings(child))
    return sorted(set(found))


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also documents every command in ``--help``)."""
    parser = _Parser(
        prog="admm-dolfinx",
        description="Frictionless contact of an elastic body with a rigid obstacle, solved "
        "by ADMM with the automatic penalty r* (Koko 2019). Run under mpirun for parallel.",
    )
    # -v is accepted before and after the command: the subcommands share it, and their
    # copy only sets it when given (SUPPRESS), so it never resets the main parser's.
    verbose = _Parser(add_help=False)
    verbose.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        default=argparse.SUPPRESS,
        help=_VERBOSE_HELP,
    )
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help=_VERBOSE_HELP,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run",
        parents=[verbose],
        help="solve one scene and print the result summary",
        description="Solve one of the package's scenes: example1 (rectangle "
        "on a foundation), example2 (Hertz quarter cylinder), example3 "
        "(block on a half-ball), the paper's; hertz (a quarter cylinder on a plane) "
        "and hertz_sphere (a quarter sphere on a plane), Hertz's; or your own gmsh mesh "
        "with --mesh.",
    )
    run.add_argument("scene", nargs="?", choices=sorted(SCENES))
    run.add_argument("--h", type=float, default=None, help="example1: mesh size (1/32)")
    run.add_argument(
        "--mesher",
        choices=["gmsh", "builtin"],
        default=None,
        help="example1: unstructured gmsh (default) or structured DOLFINx mesh",
    )
    run.add_argument(
        "--level",
        type=int,
        default=None,
        help="the other scenes: mesh level (0, default; each level halves the element size)",
    )
    own = run.add_argument_group(
        "your own mesh",
        "Run a gmsh .msh file instead of a scene: its boundary parts are physical groups "
        "of facets, named here by their tags. Example: run --mesh part.msh --contact 3 "
        "--fixed 1 --traction 4:0,0,-10 --plane 0,0,-0.01/0,0,1",
    )
    own.add_argument("--mesh", default=None, metavar="FILE", help="a gmsh .msh file")
    own.add_argument("--contact", type=int, metavar="TAG", help="tag of the contact facets")
    own.add_argument(
        "--fixed", type=int, action="append", metavar="TAG", help="clamp these facets (u = 0)"
    )
    own.add_argument(
        "--displace",
        type=_tagged_vector,
        action="append",
        metavar="TAG:VECTOR",
        help="prescribe the displacement of these facets, e.g. 2:0,-0.01",
    )
    own.add_argument(
        "--traction",
        type=_tagged_vector,
        action="append",
        metavar="TAG:VECTOR",
        help="a surface traction on these facets (force per area), e.g. 4:0,0,-10",
    )
    own.add_argument(
        "--body-force", type=_numbers, metavar="VECTOR", help="force per volume, e.g. 0,-9.8"
    )
    own.add_argument(
        "--plane",
        type=_two_parts,
        metavar="POINT/NORMAL",
        help="a rigid plane; the normal points from it towards the body",
    )
    own.add_argument("--ball", type=_two_parts, metavar="CENTRE/RADIUS", help="a rigid ball")
    own.add_argument("--E", type=float, default=1000.0, help="Young's modulus (1000)")
    own.add_argument("--nu", type=float, default=0.3, help="Poisson's ratio (0.3)")
    run.add_argument(
        "--penalty", type=_penalty, default="auto", help="penalty r, or 'auto' for r* (default)"
    )
    run.add_argument(
        "--mode",
        choices=["accelerated", "paper"],
        default="accelerated",
        help="accelerated ADMM with the KKT stopping test (default), or the paper's "
        "algorithm and relative-change test",
    )
    run.add_argument(
        "--rtol", type=float, default=None, help="stopping tolerance (default: the mode's)"
    )
    run.add_argument("--max-iter", type=int, default=1000, help="iteration cap")
    polish = run.add_mutually_exclusive_group()
    polish.add_argument(
        "--polish",
        dest="polish",
        action="store_const",
        const=True,
        default=None,
        help="finish with active-set polishing on the dense Schur complement onto the "
        "contact dofs, in 3D too (by default in 2D, and in 3D for a body that the contact "
        "alone holds, where it is cheap)",
    )
    polish.add_argument(
        "--no-polish",
        dest="polish",
        action="store_const",
        const=False,
        help="do not finish with active-set polishing (on by default where the Schur "
        "complement onto the contact dofs is cheap: 2D, and floating 3D bodies)",
    )
    run.add_argument(
        "--penalty-metric",
        choices=["auto", "mass", "surface"],
        default="auto",
        help="norm of the penalty: the paper's r M, or r(M + βL_Γ) on the contact surface "
        "(auto: the surface metric in 3D)",
    )
    run.add_argument(
        "--contact-normal",
        choices=["obstacle", "body"],
        default=None,
        help="measure non-penetration along the obstacle's normal (default) or along the "
        "body's normal (the paper's model; the default with --mode paper)",
    )
    run.add_argument("--json", help="write a JSON summary to this file")
    run.add_argument(
        "--out",
        help="write solution.xdmf, the figures and summary.json into this folder (created "
        "if need be; nothing else in it is touched)",
    )
    run.set_defaults(func=cmd_run)

    rep = sub.add_parser(
        "reproduce",
        parents=[verbose],
        help="regenerate the paper's Tables 1-6",
        description="Regenerate a table of the paper from scratch: the "
        "paper's numbers and ours side by side, as markdown on the "
        "terminal and a CSV file. 'all' runs the six tables.",
    )
    rep.add_argument("table", choices=[*TABLES, "all"])
    rep.add_argument("--out", default="out_reproduce", help="folder for the CSV files")
    rep.add_argument(
        "--quick",
        action="store_true",
        help="fewer meshes and samples (a smoke test, not the paper's tables)",
    )
    rep.set_defaults(func=cmd_reproduce)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``admm-dolfinx``."""
    args = build_parser().parse_args(argv)
    # The package's own log (rank 0, stderr): every ADMM iteration with -v; otherwise a
    # `run` shows its stages and a progress line every few seconds of a long solve, and
    # `reproduce` (which prints its own progress) only warnings.
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    quiet = logging.WARNING if args.command == "reproduce" else logging.INFO
    logging.getLogger("admm_dolfinx").setLevel(logging.DEBUG if args.verbose else quiet)
    try:
        return args.func(args)
    except (OSError, ValueError) as error:  # an output path or bad input: every rank
        if args.verbose:
            raise
        if MPI.COMM_WORLD.rank == 0:
            print(f"admm-dolfinx: error: {error}", file=sys.stderr, flush=True)
        return 1


if __name__ == "__main__":
    sys.exit(main())
