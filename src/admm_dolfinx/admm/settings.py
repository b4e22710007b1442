"""The solver's settings: one frozen, validated object, with the paper's algorithm a preset.

OSQP's lesson: every setting has one documented default, an unknown name is an error
(with the closest known names), conflicting values raise, and nothing is silently
overridden. ``mode`` selects a preset: ``"accelerated"`` (the default) or ``"paper"``
(Algorithm 2 of Koko 2019: no over-relaxation, no acceleration, the relative-change
test at the paper's tolerance). A preset fixes the settings that define its
algorithm; passing a different value for one of them alongside it is an error.

A user sets the few of :data:`USER_SETTINGS` by name. The others
(:data:`EXPERT_SETTINGS`: the algorithm's knobs for studies and tuning) go in one
explicit group, ``expert={"alpha": 1.2}``; an expert name passed on its own, or a
removed name, raises with the spelling to use (:data:`RENAMED`). The step-1 solver is
configured through ``petsc_options`` alone (its tolerance is ``ksp_rtol``).

Options prefixes are deterministic: ``petsc_options_prefix`` (default ``"admm_"``),
and under it one derived prefix per inner solver (:attr:`ADMMSettings.prefixes`), so
that each can be tuned through PETSc's options database.
"""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any

from admm_dolfinx._mpi import check_same_on_every_rank

__all__ = [
    "CHANGE_TEST_KKT_TOL",
    "DEFAULT_PREFIX",
    "EXPERT_SETTINGS",
    "MODES",
    "PAPER_RTOL",
    "RENAMED",
    "USER_SETTINGS",
    "ADMMSettings",
]

#: The settings a user sets, by name (the README's table).
USER_SETTINGS = (
    "penalty",
    "mode",
    "rtol",
    "max_iter",
    "polish",
    "step1",
    "petsc_options",
    "petsc_options_prefix",
)
#: The algorithm's knobs for studies and tuning: passed together as ``expert={...}``.
EXPERT_SETTINGS = (
    "kkt_tol",
    "alpha",
    "anderson",
    "stopping",
    "penalty_method",
    "penalty_tol",
    "penalty_metric",
    "condensed",
    "polish_rounds",
    "inner_sigma",
)
#: Names that are gone, and how to say the same thing now.
RENAMED = {
    "step1_rtol": (
        "the step-1 tolerance is PETSc's ksp_rtol: pass petsc_options={'ksp_rtol': value} "
        "for a fixed one (by default it follows the outer residual)"
    ),
    "ksp_rtol": "pass petsc_options={'ksp_rtol': value}",
}

#: Tolerance of the paper's relative-change test. With it, Example 1 needs the
#: iteration counts of the paper's Table 1, so it is taken to be the paper's tolerance
#: (``admm-dolfinx reproduce table1`` prints both).
PAPER_RTOL = 1e-5
#: Default ``kkt_tol`` with the relative-change test: that test bounds the changes of
#: u and p, not the residuals, which it leaves larger where ADMM contracts slowly (a
#: floating body at r*, a penalty at the edge of the paper's sampling range); a
#: stagnated iteration (an r orders of magnitude off) is far above it.
CHANGE_TEST_KKT_TOL = 1e-2
#: The default options prefix of a solver (DOLFINx's solvers make it mandatory; here
#: it is fixed, so that the same script always reads the same options).
DEFAULT_PREFIX = "admm_"

_STOPPING = ("kkt", "change")
_METRICS = ("auto", "mass", "surface")
_PENALTY_METHODS = ("auto", "dense", "local", "factorised")
_STEP1 = ("auto", "factorised", "iterative")
#: The preconditioners that solve on their own, with ``ksp_type`` ``preonly``.
_DIRECT_PCS = ("cholesky", "lu", "svd", "redundant")
#: The presets: the values each mode starts from. The defaults of the accelerated mode
#: were chosen by ``benchmarks/acceleration.py``.
PRESETS: dict[str, dict[str, Any]] = {
    "accelerated": {
        "alpha": 1.6,
        "anderson": 5,
        "stopping": "kkt",
        "rtol": 1e-6,
        "polish": None,
        "penalty_metric": "auto",
    },
    "paper": {
        "alpha": 1.0,
        "anderson": 0,
        "stopping": "change",
        "rtol": PAPER_RTOL,
        "polish": False,
        "penalty_metric": "mass",
    },
}
MODES = tuple(PRESETS)
#: The settings a preset fixes: an explicit different value conflicts with the mode
#: (``rtol`` is only the preset's default).
FIXED_BY = {
    "accelerated": (),
    "paper": ("alpha", "anderson", "stopping", "polish", "penalty_metric"),
}


def _real(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {value!r}.")
    return float(value)


def _optional_fraction(name: str, value: Any, chooser: str) -> float | None:
    """None, or a real number in (0, 1); ``chooser`` says who picks it when None."""
    if value is None:
        return None
    value = _real(name, value)
    if not 0.0 < value < 1.0:
        raise ValueError(
            f"{name} must lie in (0, 1) (or None: chosen by {chooser}), got {value!r}."
        )
    return value


def _integer(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an int, got {value!r}.")
    return int(value)


def _choice(name: str, value: Any, choices: tuple) -> Any:
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}.")
    return value


def _switch(name: str, value: Any) -> bool | None:
    if value is not None and not isinstance(value, bool):
        raise TypeError(f"{name} must be None (automatic), True or False, got {value!r}.")
    return value


def _flatten(given: Mapping[str, Any], expert: Mapping[str, Any] | None) -> dict[str, Any]:
    """One dict of setting values from the user's names and the ``expert`` group.

    Raises:
        TypeError: For an unknown or removed name, an expert setting outside ``expert``,
            a user setting inside it, or an ``expert`` that is not a mapping.
    """
    if expert is not None and not isinstance(expert, Mapping):
        raise TypeError(f"expert must be a mapping of expert settings, got {expert!r}.")
    expert = dict(expert or {})
    problems = []
    for name, value in given.items():
        if name in EXPERT_SETTINGS:
            problems.append(f"{name!r} is an expert setting: pass expert={{{name!r}: {value!r}}}")
        elif name in RENAMED:
            problems.append(f"{name!r} is gone: {RENAMED[name]}")
        elif name not in USER_SETTINGS:
            hint = _closest(name, USER_SETTINGS, EXPERT_SETTINGS)
            problems.append(f"{name!r} is not a setting{hint}")
    for name in expert:
        if name in USER_SETTINGS:
            problems.append(f"{name!r} is a setting of its own: pass {name}=..., not in expert")
        elif name in RENAMED:
            problems.append(f"{name!r} is gone: {RENAMED[name]}")
        elif name not in EXPERT_SETTINGS:
            hint = _closest(name, (), EXPERT_SETTINGS)
            problems.append(f"{name!r} is not an expert setting{hint}")
    if problems:
        raise TypeError(
            "ADMM settings: "
            + "; ".join(problems)
            + f". Settings: {', '.join(USER_SETTINGS)}; in expert={{...}}: "
            + f"{', '.join(EXPERT_SETTINGS)}."
        )
    return {**given, **expert}


def _closest(name: str, user: tuple[str, ...], expert: tuple[str, ...]) -> str:
    """' (did you mean ...?)' with the closest names, each spelled as it is passed."""
    spelled = {n: n for n in user} | {n: f"expert={{{n!r}: ...}}" for n in expert}
    close = difflib.get_close_matches(name, list(spelled), n=2)
    return f" (did you mean {' or '.join(spelled[n] for n in close)}?)" if close else ""


def check_penalty(r: Any) -> float:
    """A penalty r given by hand: a positive finite real number, else a clear error."""
    try:
        value = float(r)
    except (TypeError, ValueError):
        raise TypeError(f"penalty must be a positive number or 'auto', got {r!r}.") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(
            f"penalty r must be a positive finite number, got {r!r}. Use penalty='auto' "
            "for the automatic choice r* = 1/sqrt(λ_min λ_max), or a value of the order "
            "of Young's modulus."
        )
    return value


@dataclass(frozen=True)
class ADMMSettings:
    """Validated settings of :class:`~admm_dolfinx.ADMMSolver` (build with :meth:`create`).

    Every setting reads as an attribute; :data:`USER_SETTINGS` are given by name,
    :data:`EXPERT_SETTINGS` in ``expert={...}`` (``kkt_tol`` to ``polish_rounds``, and
    ``inner_sigma``, below).

    Attributes:
        penalty: Penalty parameter r > 0, or ``"auto"``: r* = 1/sqrt(λ_min λ_max) (in
            3D with the surface metric, its own r and β).
        mode: ``"accelerated"`` or ``"paper"``: the preset (see the module docstring).
        rtol: Tolerance of the stopping test.
        kkt_tol: Tolerance of the final check of the KKT residuals recomputed from
            (u, λ); ``converged=True`` only if they are all ≤ it. Default: ``rtol``
            with the ``"kkt"`` test, :data:`CHANGE_TEST_KKT_TOL` with ``"change"``.
        max_iter: Maximum number of iterations (≥ 1).
        alpha: Over-relaxation α ∈ (0, 2); 1 is plain ADMM.
        anderson: Anderson memory k ≥ 0; 0 switches acceleration off.
        stopping: ``"kkt"`` (fixed-point and KKT residuals) or ``"change"`` (the
            paper's relative changes of u and p).
        penalty_method: How r* is computed: ``"dense"`` (the whole pencil from the
            condensed stiffness: exact; 2D-sized Γ_C), ``"local"`` (λ_min on layers
            along Γ_C, λ_max by multigrid LOBPCG: no factorisation of the body),
            ``"factorised"`` (both ends from factorisations of the body: exact to
            ``penalty_tol``, the same on any partition), or ``"auto"``: dense where the
            condensed factorisation is cheap (:mod:`admm_dolfinx.operators.condensed`),
            local otherwise.
        penalty_tol: Eigenvalue tolerance of the iterative r* methods, in (0, 1), or
            None: :data:`~admm_dolfinx.penalty.estimate.DEFAULT_PENALTY_TOL` for the
            paper's metric, whose r is r*, and
            :data:`~admm_dolfinx.penalty.surface.SURFACE_PENALTY_TOL` for the surface
            metric, whose β and r take λ_min and λ_max through factors calibrated on a
            grid of factors of 2 (``solver.plan.penalty_tol`` is the one used).
        penalty_metric: The norm of the penalty term: ``"mass"`` (the paper's r M),
            ``"surface"`` (r(M + βL_Γ), 3D), or ``"auto"`` (surface in 3D with an
            automatic penalty and no polishing, or the multigrid path's, which does
            not depend on r; mass otherwise).
        condensed: Step 1 through one factorisation of A condensed onto Γ_C (None:
            where it also gives r*, i.e. 2D or a floating 3D body whose S_C is cheap,
            one process, ``penalty="auto"``, and not with the surface metric).
        polish: Active-set polishing (None: with ``penalty="auto"`` and a factorised
            step 1, in 2D, and in 3D for a body that the contact alone holds, where
            S_C is cheap; with an iterative step 1, for a body that the contact alone
            holds, by multigrid solves; True also in 3D; False: never).
        polish_rounds: New primal-dual active-set corrections per dense polishing
            attempt (an attempt that joins an earlier walk resumes it).
        step1: How step 1 solves with A + rK: ``"factorised"`` (MUMPS Cholesky, one
            factorisation per r), ``"iterative"`` (conjugate gradients with multigrid,
            warm-started, to a tolerance tied to the outer residual: an inexact ADMM),
            or ``"auto"``: iterative if ``petsc_options`` choose a Krylov method, or,
            in 3D, if the factorisation would not fit in memory or would cost more
            than the multigrid path (bracketed from the mesh, or MUMPS's analysis near
            the thresholds: :mod:`admm_dolfinx.admm.plan`); factorised otherwise.
        petsc_options: Options of the step-1 solver (MUMPS Cholesky, or with an
            iterative step 1 CG + GAMG stopping on the unpreconditioned residual, by
            default; ``ksp_rtol`` fixes an iterative step 1's tolerance, which otherwise
            follows the outer residual by the inexact rule of
            :mod:`admm_dolfinx.admm.inexact`). Step 1 only: each inner solver (r*,
            the Schur complement, polishing, the surface metric) takes its defaults and
            the PETSc options database under its own prefix (:attr:`prefixes`).
        petsc_options_prefix: The solver's options prefix (see :attr:`prefixes`).
        inner_sigma: σ of the inexact rule of an iterative step 1 (its tolerance is
            σ r_{k−1} once the outer residual is small), in (0, 1), or None: chosen by
            the plan, :data:`~admm_dolfinx.admm.inexact.SIGMA_HELD` for a body held by
            its Dirichlet conditions, :data:`~admm_dolfinx.admm.inexact.SIGMA_FLOATING`
            for one that the contact alone holds. Refused where step 1 may be
            factorised or its tolerance is fixed (``ksp_rtol``): it would go unused.
    """

    penalty: float | str = "auto"
    mode: str = "accelerated"
    rtol: float = PRESETS["accelerated"]["rtol"]
    kkt_tol: float = PRESETS["accelerated"]["rtol"]
    max_iter: int = 1000
    alpha: float = PRESETS["accelerated"]["alpha"]
    anderson: int = PRESETS["accelerated"]["anderson"]
    stopping: str = PRESETS["accelerated"]["stopping"]
    penalty_method: str = "auto"
    penalty_tol: float | None = None
    penalty_metric: str = "auto"
    condensed: bool | None = None
    polish: bool | None = None
    polish_rounds: int = 10
    step1: str = "auto"
    petsc_options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    petsc_options_prefix: str = DEFAULT_PREFIX
    inner_sigma: float | None = None

    @classmethod
    def create(cls, *, expert: Mapping[str, Any] | None = None, **given: Any) -> ADMMSettings:
        """Validated settings from the given values, the mode's preset and the defaults.

        Args:
            expert: Values of :data:`EXPERT_SETTINGS`, by name.
            **given: Values of :data:`USER_SETTINGS`, by name.

        Raises:
            TypeError: For an unknown or removed name (the spelling to use is named), an
                expert setting passed on its own, or a value of the wrong type.
            ValueError: For a value out of range, or one that conflicts with the mode.
        """
        return cls._from_values(_flatten(given, expert))

    @classmethod
    def _from_values(cls, given: dict[str, Any]) -> ADMMSettings:
        """Validated settings from every setting's value by name (None: not given)."""
        # None is "not given" (the default or the preset's value)
        given = {k: v for k, v in given.items() if v is not None}
        mode = _choice("mode", given.get("mode", "accelerated"), MODES)
        preset = PRESETS[mode]
        for name in FIXED_BY[mode]:
            automatic = name == "penalty_metric" and given.get(name) == "auto"
            if name in given and given[name] != preset[name] and not automatic:
                spelled = f"{name}=" if name in USER_SETTINGS else f"expert {name}="
                raise ValueError(
                    f"mode={mode!r} fixes {name} = {preset[name]!r} (it is the paper's "
                    f"algorithm); you also passed {spelled}{given[name]!r}. Drop one of "
                    "them: for other values use mode='accelerated'."
                )
        values = {**preset, **given, "mode": mode}
        if mode == "paper" and values["penalty_metric"] == "auto":
            values["penalty_metric"] = "mass"
        rtol = _real("rtol", values["rtol"])
        if not (math.isfinite(rtol) and rtol > 0.0):
            raise ValueError(f"rtol must be a positive finite number, got {rtol!r}.")
        stopping = _choice("stopping", values["stopping"], _STOPPING)
        kkt_tol = values.get("kkt_tol")
        kkt_tol = (
            (rtol if stopping == "kkt" else CHANGE_TEST_KKT_TOL) if kkt_tol is None else kkt_tol
        )
        kkt_tol = _real("kkt_tol", kkt_tol)
        if not (math.isfinite(kkt_tol) and kkt_tol > 0.0):
            raise ValueError(f"kkt_tol must be a positive finite number, got {kkt_tol!r}.")
        if stopping == "kkt" and kkt_tol < rtol:
            raise ValueError(
                f"kkt_tol = {kkt_tol:g} is below rtol = {rtol:g}: with the 'kkt' stopping "
                "test the loop stops at rtol, so the final check could never pass. Lower "
                "rtol instead."
            )
        max_iter = _integer("max_iter", values.get("max_iter", 1000))
        if max_iter < 1:
            raise ValueError(f"max_iter must be at least 1, got {max_iter}.")
        alpha = _real("alpha", values["alpha"])
        if not 0.0 < alpha < 2.0:
            raise ValueError(f"alpha (over-relaxation) must lie in (0, 2), got {alpha}.")
        anderson = _integer("anderson", values["anderson"])
        if anderson < 0:
            raise ValueError(f"anderson (memory) must be ≥ 0 (0: off), got {anderson}.")
        penalty_tol = _optional_fraction("penalty_tol", values.get("penalty_tol"), "the metric")
        penalty = values.get("penalty", "auto")
        if not (isinstance(penalty, str) and penalty == "auto"):
            penalty = check_penalty(penalty)
        polish_rounds = _integer("polish_rounds", values.get("polish_rounds", 10))
        if polish_rounds < 1:
            raise ValueError(f"polish_rounds must be at least 1, got {polish_rounds}.")
        inner_sigma = _optional_fraction("inner_sigma", values.get("inner_sigma"), "the plan")
        prefix = values.get("petsc_options_prefix", DEFAULT_PREFIX)
        if not isinstance(prefix, str) or not prefix or prefix.startswith("-"):
            raise ValueError(
                f"petsc_options_prefix must be a non-empty string without a leading '-', "
                f"got {prefix!r}."
            )
        options = values.get("petsc_options") or {}
        if not isinstance(options, Mapping):
            raise TypeError(f"petsc_options must be a mapping of PETSc options, got {options!r}.")
        step1 = _choice("step1", values.get("step1", "auto"), _STEP1)
        if "ksp_rtol" in options:
            try:  # PETSc takes option values as strings too
                ksp_rtol = float(options["ksp_rtol"])
            except (TypeError, ValueError):
                raise TypeError(
                    f"petsc_options ksp_rtol must be a number, got {options['ksp_rtol']!r}."
                ) from None
            if not 0.0 < ksp_rtol < 1.0:
                raise ValueError(f"petsc_options ksp_rtol must lie in (0, 1), got {ksp_rtol}.")
        krylov = options.get("ksp_type", "preonly") != "preonly"
        direct = options.get("pc_type", "cholesky") in _DIRECT_PCS
        if not krylov and not direct:
            raise ValueError(
                f"petsc_options {dict(options)} apply the preconditioner "
                f"pc_type={options['pc_type']!r} once (ksp_type 'preonly'): that solves "
                "nothing. Use a factorisation (pc_type 'cholesky' or 'lu'; the default), or "
                "a Krylov method with it (ksp_type 'cg')."
            )
        if step1 == "factorised" and krylov:
            raise ValueError(
                f"step1='factorised' conflicts with petsc_options ksp_type="
                f"{options['ksp_type']!r} (an iterative method): drop one of them."
            )
        if step1 == "iterative" and "ksp_type" in options and not krylov:
            raise ValueError(
                "step1='iterative' conflicts with petsc_options ksp_type='preonly' (a "
                "direct solve): drop one of them."
            )
        if "ksp_rtol" in options and not (step1 == "iterative" or krylov):
            raise ValueError(
                "petsc_options ksp_rtol is the tolerance of an iterative step 1, and this "
                f"step 1 (step1={step1!r}, no ksp_type) may be factorised, which solves "
                "exactly: pass step1='iterative' with it, or drop ksp_rtol."
            )
        # like ksp_rtol, σ is refused where step 1 may be factorised: never silently unused
        if inner_sigma is not None and (
            "ksp_rtol" in options or not (step1 == "iterative" or krylov)
        ):
            why = (
                "petsc_options ksp_rtol fixes the tolerance instead"
                if "ksp_rtol" in options
                else f"this step 1 (step1={step1!r}, no ksp_type) may be factorised, which has none"
            )
            raise ValueError(
                "expert inner_sigma sets the inexact rule of an iterative step 1, and "
                f"{why}: pass step1='iterative' with it and no ksp_rtol, or drop it."
            )
        settings = cls(
            penalty=penalty,
            mode=mode,
            rtol=rtol,
            kkt_tol=kkt_tol,
            max_iter=max_iter,
            alpha=alpha,
            anderson=anderson,
            stopping=stopping,
            penalty_method=_choice(
                "penalty_method", values.get("penalty_method", "auto"), _PENALTY_METHODS
            ),
            penalty_tol=penalty_tol,
            penalty_metric=_choice("penalty_metric", values["penalty_metric"], _METRICS),
            condensed=_switch("condensed", values.get("condensed")),
            polish=_switch("polish", values["polish"]),
            polish_rounds=polish_rounds,
            step1=step1,
            petsc_options=MappingProxyType(dict(options)),
            petsc_options_prefix=prefix,
            inner_sigma=inner_sigma,
        )
        settings._check_combinations()
        return settings

    def _check_combinations(self) -> None:
        auto = self.penalty == "auto"
        if self.step1 == "iterative":
            for name in ("condensed", "polish"):
                if getattr(self, name) is True:
                    spelled = "polish=True" if name == "polish" else "expert condensed=True"
                    raise ValueError(
                        f"{spelled} needs the Schur complement from a factorisation; "
                        "step1='iterative' has none: drop one of them."
                    )
        if self.penalty_metric == "surface":
            for failed, reason in (
                (not auto, "chooses r and β itself: pass penalty='auto'"),
                (self.polish is True, "and polish=True exclude each other"),
            ):
                if failed:
                    raise ValueError(
                        f"expert penalty_metric='surface' {reason} (or pass "
                        "expert={'penalty_metric': 'mass'})."
                    )
        if not auto and self.penalty_method != "auto":
            raise ValueError(
                f"expert penalty_method={self.penalty_method!r} chooses how r* is computed, "
                f"but the penalty is given (r = {self.penalty}): pass penalty='auto' or drop "
                "penalty_method."
            )

    def replace(self, *, expert: Mapping[str, Any] | None = None, **changes: Any) -> ADMMSettings:
        """A validated copy with some settings changed (``kkt_tol`` follows a new rtol).

        Args:
            expert: New values of :data:`EXPERT_SETTINGS` (the others are kept).
            **changes: New values of :data:`USER_SETTINGS`.
        """
        changes = _flatten(changes, expert)
        current = {f.name: getattr(self, f.name) for f in fields(self)}
        if "rtol" in changes or "stopping" in changes or "mode" in changes:
            current.pop("kkt_tol")  # it follows the test and tolerance, unless given
        if "mode" in changes:  # a new preset: keep only what is not the old preset's
            for name in PRESETS[self.mode]:
                current.pop(name, None)
        return ADMMSettings._from_values({**current, **changes})

    @property
    def expert(self) -> dict[str, Any]:
        """The values of :data:`EXPERT_SETTINGS`, by name."""
        return {name: getattr(self, name) for name in EXPERT_SETTINGS}

    @property
    def prefixes(self) -> dict[str, str]:
        """The options prefix of each inner solver, derived from the solver's prefix.

        ``step1`` (the factorisation or KSP of step 1), ``penalty`` (r*: ``dense_``,
        ``layer_``, ``lmin_``, ``lmax_``, ``amg_`` below it), ``surface`` (μ_max of the
        surface metric), ``projection`` (the surface metric's step 2: the factorisations
        of M + βL_Γ on the free contact nodes), ``polish`` (sparse polishing's
        factorisations), ``schur`` (a private condensed factorisation for r* and
        polishing), ``estimate`` (MUMPS's analysis, which the plan runs in 3D where the mesh's
        bracket of the cost does not settle the choice).
        """
        p = self.petsc_options_prefix
        return {
            "step1": f"{p}step1_",
            "penalty": f"{p}penalty_",
            "surface": f"{p}surface_",
            "projection": f"{p}projection_",
            "polish": f"{p}polish_",
            "schur": f"{p}schur_",
            "estimate": f"{p}estimate_",
        }

    def as_dict(self) -> dict[str, Any]:
        """Plain values (for JSON and reports): the user's settings, then ``expert``."""
        out = {name: getattr(self, name) for name in USER_SETTINGS}
        out["petsc_options"] = dict(self.petsc_options)
        out["expert"] = self.expert
        return out

    def check_same_on_every_rank(self, comm: Any) -> None:
        """Raise on every rank if some setting differs between the ranks; collective.

        Raises:
            ValueError: On every rank alike, naming each setting that differs (see
                :func:`admm_dolfinx._mpi.check_same_on_every_rank`).
        """
        flat = {f.name: getattr(self, f.name) for f in fields(self)}  # each by its name
        flat["petsc_options"] = dict(self.petsc_options)
        check_same_on_every_rank(comm, flat, "The solver's settings")
