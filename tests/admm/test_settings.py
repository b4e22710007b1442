"""The settings object: validated, frozen, presets that never override silently; the plan.

OSQP's rules: an unknown name is an error (with the closest known names), conflicting
values raise, nothing is silently overridden; a preset (``mode="paper"``) fixes the
settings of its algorithm, and an explicit different value is an error.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import fields

import numpy as np
import pytest
from mpi4py import MPI

from admm_dolfinx import ADMMSettings, ADMMSolver
from admm_dolfinx.admm.settings import EXPERT_SETTINGS, PAPER_RTOL, USER_SETTINGS
from admm_dolfinx.scenes import example1, example3


@pytest.fixture(scope="module")
def problem():
    return example1(MPI.COMM_WORLD, h=1 / 8, mesher="builtin").problem()


def test_defaults_and_presets():
    fast = ADMMSettings.create()
    assert (fast.alpha, fast.anderson, fast.stopping, fast.rtol) == (1.6, 5, "kkt", 1e-6)
    assert fast.kkt_tol == fast.rtol
    paper = ADMMSettings.create(mode="paper")
    assert (paper.alpha, paper.anderson, paper.stopping, paper.polish) == (1.0, 0, "change", False)
    assert paper.rtol == PAPER_RTOL and paper.kkt_tol == 1e-2
    assert ADMMSettings.create(mode="paper", rtol=1e-7).rtol == 1e-7  # rtol: only a default
    # a preset value given explicitly is no conflict
    assert ADMMSettings.create(mode="paper", expert={"alpha": 1.0}).alpha == 1.0


@pytest.mark.parametrize(
    "name,value",
    [
        ("alpha", 1.6),
        ("anderson", 5),
        ("stopping", "kkt"),
        ("polish", True),
        ("penalty_metric", "surface"),
    ],
)
def test_paper_mode_refuses_a_conflicting_value(name, value, problem):
    given = {name: value} if name in USER_SETTINGS else {"expert": {name: value}}
    with pytest.raises(ValueError, match=rf"mode='paper' fixes {name}"):
        ADMMSettings.create(mode="paper", **given)
    with pytest.raises(ValueError, match=rf"mode='paper' fixes {name}"):
        ADMMSolver(problem, mode="paper", **given)


def test_unknown_names_are_refused_with_a_suggestion(problem):
    with pytest.raises(
        TypeError, match=r"'alpah' is not a setting \(did you mean expert=\{'alpha'"
    ):
        ADMMSettings.create(alpah=1.5)
    with pytest.raises(TypeError, match=r"'max_iters' is not a setting \(did you mean max_iter"):
        ADMMSolver(problem, max_iters=10)
    with pytest.raises(TypeError, match=r"'anderzon' is not an expert setting \(did you mean"):
        ADMMSettings.create(expert={"anderzon": 3})


def test_the_user_surface_is_the_few_settings_and_the_expert_group(problem):
    """An expert setting by name, a user setting in expert, or an old name: each raises
    with the spelling to use (no silent aliasing)."""
    assert len(USER_SETTINGS) == 8 and not set(USER_SETTINGS) & set(EXPERT_SETTINGS)
    assert set(USER_SETTINGS) | set(EXPERT_SETTINGS) == {f.name for f in fields(ADMMSettings)}
    with pytest.raises(
        TypeError, match=r"'alpha' is an expert setting: pass expert=\{'alpha': 1.2\}"
    ):
        ADMMSolver(problem, alpha=1.2)
    with pytest.raises(TypeError, match=r"'rtol' is a setting of its own: pass rtol="):
        ADMMSettings.create(expert={"rtol": 1e-8})
    with pytest.raises(TypeError, match=r"'step1_rtol' is gone: .*petsc_options=\{'ksp_rtol'"):
        ADMMSettings.create(step1_rtol=1e-8)
    with pytest.raises(TypeError, match="expert must be a mapping"):
        ADMMSettings.create(expert=[("alpha", 1.2)])
    settings = ADMMSettings.create(rtol=1e-8, expert={"alpha": 1.2, "anderson": 0})
    assert (settings.rtol, settings.alpha, settings.anderson) == (1e-8, 1.2, 0)
    assert settings.expert["alpha"] == 1.2 and settings.as_dict()["expert"]["anderson"] == 0
    # replace keeps the other expert values, and validates like create
    assert settings.replace(expert={"anderson": 3}).alpha == 1.2
    with pytest.raises(TypeError, match="is an expert setting"):
        settings.replace(anderson=3)


@pytest.mark.parametrize(
    "options,message",
    [
        ({"rtol": 0.0}, "rtol must be a positive"),
        ({"expert": {"alpha": 2.0}}, "alpha"),
        ({"expert": {"anderson": -1}}, "anderson"),
        ({"max_iter": 0}, "max_iter"),
        ({"expert": {"penalty_tol": 1.5}}, "penalty_tol"),
        ({"expert": {"stopping": "often"}}, "stopping must be one of"),
        ({"penalty": -1.0}, "positive finite"),
        ({"penalty": 3.0, "expert": {"penalty_metric": "surface"}}, "chooses r and β itself"),
        ({"penalty": 3.0, "expert": {"penalty_method": "dense"}}, "penalty is given"),
        ({"rtol": 1e-6, "expert": {"kkt_tol": 1e-8}}, "below rtol"),
        ({"petsc_options_prefix": "-x"}, "prefix"),
    ],
)
def test_bad_values_raise(options, message):
    with pytest.raises((TypeError, ValueError), match=message):
        ADMMSettings.create(**options)


def test_settings_are_frozen_and_replace_validates():
    settings = ADMMSettings.create(rtol=1e-7)
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.rtol = 1e-8  # type: ignore[misc]
    tighter = settings.replace(rtol=1e-9)
    assert tighter.rtol == tighter.kkt_tol == 1e-9 and settings.rtol == 1e-7
    with pytest.raises(ValueError):
        settings.replace(expert={"alpha": 3.0})


def test_prefixes_are_deterministic_and_derived():
    prefixes = ADMMSettings.create(petsc_options_prefix="mine_").prefixes
    assert prefixes["step1"] == "mine_step1_" and prefixes["penalty"] == "mine_penalty_"
    assert len(set(prefixes.values())) == len(prefixes)
    assert ADMMSettings.create().prefixes == ADMMSettings.create().prefixes


def test_the_plan_is_printable_before_a_solve(problem):
    with ADMMSolver(problem) as solver:
        plan = solver.plan
        text = solver.summary()
    assert plan.penalty == "dense" and plan.polish == "dense" and plan.metric == "mass"
    assert "2D" in plan.describe() and "polish dense" in text
    three = example3(MPI.COMM_WORLD, level=0).problem()
    with ADMMSolver(three) as solver:
        assert solver.plan.metric == "surface" and solver.plan.penalty == "local"
    with ADMMSolver(three, expert={"penalty_method": "factorised", "penalty_tol": 1e-8}) as solver:
        assert solver.penalty_estimate.details["method"] == "factorised"


def test_penalty_tolerance_follows_the_metric(problem):
    """penalty_tol=None: 1e-2 for r* in the paper's metric, the looser surface-metric
    tolerance where λ_min and λ_max only feed β and r; the eigensolves run at the
    plan's tolerance; a given tolerance is kept in both; a given penalty has none."""
    from admm_dolfinx.penalty.estimate import DEFAULT_PENALTY_TOL
    from admm_dolfinx.penalty.surface import SURFACE_PENALTY_TOL

    assert ADMMSettings.create().penalty_tol is None
    assert SURFACE_PENALTY_TOL > DEFAULT_PENALTY_TOL
    with ADMMSolver(problem) as solver:
        assert solver.plan.metric == "mass"
        assert solver.plan.penalty_tol == DEFAULT_PENALTY_TOL
    three = example3(MPI.COMM_WORLD, level=0).problem()
    cases = (
        ({}, "surface", SURFACE_PENALTY_TOL),
        ({"expert": {"penalty_metric": "mass"}}, "mass", DEFAULT_PENALTY_TOL),
        ({"expert": {"penalty_tol": 0.05}}, "surface", 0.05),
        ({"expert": {"penalty_metric": "mass", "penalty_tol": 0.05}}, "mass", 0.05),
    )
    for options, metric, tol in cases:
        with ADMMSolver(three, **options) as solver:
            assert solver.plan.metric == metric
            assert solver.plan.penalty_tol == tol
            assert solver.penalty_estimate.details["tol"] == tol
            assert f"(tol {tol:g})" in solver.plan.describe()
    with ADMMSolver(three, penalty=1e6, expert={"penalty_metric": "mass"}) as solver:
        assert solver.plan.penalty == "given" and solver.plan.penalty_tol is None


def test_update_settings_between_solves(problem):
    with ADMMSolver(problem, polish=False) as solver:
        loose = solver.solve()
        solver.update_settings(rtol=1e-10)
        tight = solver.solve()
        assert tight.iterations > loose.iterations and tight.kkt.max() <= 1e-10
        with pytest.raises(ValueError, match="build a new ADMMSolver"):
            solver.update_settings(penalty=3.0)
    assert np.isclose(loose.settings.rtol, 1e-6) and tight.settings.rtol == 1e-10


def test_a_settings_object_is_accepted(problem):
    settings = ADMMSettings.create(mode="paper")
    with ADMMSolver(problem, settings) as solver:
        assert solver.settings == settings
    with ADMMSolver(problem, settings, rtol=1e-6) as solver:  # options on top
        assert solver.settings.rtol == 1e-6 and solver.settings.mode == "paper"


@pytest.fixture(scope="module")
def floating():
    """A small 3D body that the contact alone holds (the Hertz sphere, level 0)."""
    from admm_dolfinx.scenes import hertz_sphere

    problem = hertz_sphere(MPI.COMM_WORLD, level=0).problem()
    assert problem.rigid_motions.floating > 0
    return problem


def test_floating_3d_plans_are_consistent(floating):
    """Every combination that the settings and the plan accept builds a solver; the
    surface metric never meets dense polishing or a condensed step 1; the default
    polishes a small floating body, and without polishing it keeps the surface
    metric with the local r* that its β and r were calibrated with."""
    from admm_dolfinx.admm.plan import make_plan

    serial = floating.comm.size == 1
    for polish, condensed, metric in itertools.product(
        (None, True, False), (None, True, False), ("auto", "mass", "surface")
    ):
        options = {"polish": polish, "expert": {"condensed": condensed, "penalty_metric": metric}}
        try:
            plan = make_plan(floating, ADMMSettings.create(**options))
        except ValueError:
            continue  # refused up front, before any work
        if plan.metric == "surface":
            assert plan.polish != "dense" and plan.step1 != "condensed", options
        if plan.step1 == "condensed":
            assert serial and plan.metric == "mass", options
        with ADMMSolver(floating, **options) as solver:  # must not raise any more
            # (the reasons quote MUMPS's estimate, which a parallel ordering varies)
            assert dataclasses.replace(solver.plan, reasons=()) == dataclasses.replace(
                plan, reasons=()
            )
    refusal = "condensed step 1 cannot" if serial else "condensed=True needs one process"
    with pytest.raises(ValueError, match=refusal):
        make_plan(
            floating, ADMMSettings.create(expert={"condensed": True, "penalty_metric": "surface"})
        )
    cases = [
        ({}, ("dense", "mass", "dense")),
        ({"expert": {"penalty_metric": "surface"}}, ("none", "surface", "local")),
        ({"polish": False}, ("none", "surface", "local")),
        ({"polish": True}, ("dense", "mass", "dense")),
    ]
    for options, (polish, metric, penalty) in cases:
        plan = make_plan(floating, ADMMSettings.create(**options))
        assert (plan.polish, plan.metric, plan.penalty) == (polish, metric, penalty), options
        assert plan.step1 == ("condensed" if serial and metric == "mass" else "factorised")


def test_petsc_options_configure_step1_only(monkeypatch):
    """The user's petsc_options reach the step-1 solver and no inner solver: those take
    their defaults and their own prefix (they used to take the step-1 options too)."""
    from admm_dolfinx.linalg import petsc as petsc_helpers

    applied: list[tuple[str, dict]] = []
    original = petsc_helpers.apply_options

    def recording(obj, prefix, options, **kwargs):
        applied.append((prefix, dict(options or {})))
        return original(obj, prefix, options, **kwargs)

    monkeypatch.setattr(petsc_helpers, "apply_options", recording)
    problem = example3(MPI.COMM_WORLD, level=0).problem()
    mine = {"mat_mumps_icntl_14": 80}
    with ADMMSolver(problem, step1="factorised", petsc_options=mine) as solver:
        prefixes = solver.settings.prefixes
    step1 = [options for prefix, options in applied if prefix == prefixes["step1"]]
    inner = [(prefix, options) for prefix, options in applied if prefix != prefixes["step1"]]
    assert step1 and all(options.items() >= mine.items() for options in step1)
    # the default 3D path factorises layers along Γ_C for r*: with their defaults
    assert any(prefix.startswith(prefixes["penalty"]) and options for prefix, options in inner)
    assert not [prefix for prefix, options in inner if "mat_mumps_icntl_14" in options]


def test_estimate_penalty_alone_chooses_the_solvers_method():
    """r*'s automatic method has one home: estimate_penalty(problem) on its own picks
    the method that the solver's plan picks (2D dense, 3D local in the paper's metric)."""
    from admm_dolfinx.penalty.estimate import estimate_penalty

    for scene, expected in (
        (example1(MPI.COMM_WORLD, h=1 / 8), "dense"),
        (example3(MPI.COMM_WORLD, level=0), "local"),
    ):
        problem = scene.problem()
        with ADMMSolver(problem, expert={"penalty_metric": "mass"}) as solver:
            assert solver.plan.penalty == expected
        assert estimate_penalty(problem).details["method"] == expected


def test_a_new_mode_brings_its_own_kkt_tolerance():
    """replace(mode=...) kept the old mode's kkt_tol: paper → accelerated checked the KKT
    residuals at 1e-2 while the loop stopped at 1e-6."""
    from admm_dolfinx.admm.settings import CHANGE_TEST_KKT_TOL

    accelerated = ADMMSettings.create(mode="paper").replace(mode="accelerated")
    assert accelerated.kkt_tol == accelerated.rtol == ADMMSettings.create().rtol
    paper = ADMMSettings.create().replace(mode="paper")
    assert paper.kkt_tol == CHANGE_TEST_KKT_TOL
    # and a ksp_rtol given as PETSc often takes it, a string, is read as a number
    iterative = ADMMSettings.create(step1="iterative", petsc_options={"ksp_rtol": "1e-8"})
    assert iterative.petsc_options["ksp_rtol"] == "1e-8"
    with pytest.raises(TypeError, match="ksp_rtol must be a number"):
        ADMMSettings.create(step1="iterative", petsc_options={"ksp_rtol": "tight"})
