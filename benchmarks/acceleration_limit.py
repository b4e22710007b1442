"""How far can acceleration of the ADMM map go? The same map with the active set known.

The accelerated iteration (α = 1.6, safeguarded Anderson with memory 5, no
polishing: the 3D default) needs several times fewer iterations than the paper's
ADMM, but its count still grows under refinement. This benchmark separates the two
phases of the iteration to show where the growth comes from:

* **actual**: ``paper r*`` (α = 1, no acceleration) and the accelerated ``both, no
  polish``, both at r* from zero, as in ``benchmarks/acceleration.py``;
* **known active set**: the same ADMM map, but with the final active set 𝒜 (the
  contact nodes with λ > 0 in the reference) imposed from the first iteration. In the
  Douglas-Rachford variable w (p = g, λ = r(w − g) on 𝒜; p = w, λ = 0 off it) one
  step is the affine map

      (A + r NᵀMN) u = f + NᵀM (r p − λ),   w⁺ = α N u + (1 − α) p + w − p,

  so there is no active-set search left, only the linear convergence; it is run
  plain and with (unsafeguarded) Anderson memory 5, 20 and 100. For an affine map,
  Anderson with unlimited memory is GMRES on the fixed-point residual: the fastest
  any residual-minimising acceleration of this factorisation can be.

All runs use the same r* and the same factorisation of A + r*NᵀMN, and count the
iterations (step-1 solves) until ‖u − u_ref‖/‖u_ref‖ ≤ 1e-6 and ≤ 1e-8, with u_ref from
PETSc's SNES VI (``benchmarks/acceleration.py``'s reference).

    python benchmarks/acceleration_limit.py          # Example 1 h=1/32..1/256, Example 3 0-3
    python benchmarks/acceleration_limit.py --quick  # the two smallest of each

Writes out_benchmarks/acceleration_limit.csv.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from acceleration import TARGETS, ErrorTrace, reference, run_variant, say, write_table

import admm_dolfinx
from admm_dolfinx.admm.anderson import AndersonMixer
from admm_dolfinx.admm.settings import PRESETS

DEFAULT_ALPHA = PRESETS["accelerated"]["alpha"]
DEFAULT_ANDERSON = PRESETS["accelerated"]["anderson"]
from admm_dolfinx.operators.penalised import PenalisedOperator
from admm_dolfinx.scenes.library import example1, example3

#: The paper's contact model (along the body's normal): the README's tables of this
#: script were measured in it, and SNES VI's bounds apply to Example 3 only in it.
MODEL = "body"

MEMORIES = (0, 5, 20, 100)
MAX_ITER = 400


def known_active_set_run(problem, operator, u_ref, active, alpha, memory):
    """Iterate the ADMM map restricted to the active set `active`; the error trace."""
    contact = problem.contact
    g, r = contact.gap, operator.penalty
    trace = ErrorTrace(u_ref)
    x, b0, b = (problem.create_vector() for _ in range(3))
    problem.assemble_rhs(r, b0)
    mixer = AndersonMixer(memory, contact.mass, problem.comm) if memory else None
    w = np.minimum(0.0, g)
    try:
        for k in range(1, MAX_ITER + 1):
            p = np.where(active, g, w)
            lam = r * (w - p)
            b0.copy(b)
            problem.add_normal_force(b, r * p - lam)
            operator.solve(b, x)
            image = alpha * problem.apply_normal(x) + (1.0 - alpha) * p + w - p
            if trace(k, x, lam):
                break
            proposal = mixer.update(w, image) if mixer is not None else None
            w = image if proposal is None else proposal
    finally:
        for vec in (x, b0, b, trace.work):
            vec.destroy()
    return trace


def bench_mesh(name, scene):
    problem = scene.problem(contact_normal=MODEL)
    dofs = problem.V.dofmap.index_map.size_global * problem.gdim
    say(f"\n## {name}: {dofs} dofs, m = {problem.num_contact_nodes}")
    r = admm_dolfinx.estimate_penalty(problem).r
    u_ref, how, active = reference(problem, True)
    num_active = problem.comm.allreduce(int(np.count_nonzero(active)))
    say(f"   reference: {how}; r* = {r:.5g}; active nodes {num_active}")

    def counts(trace):
        return "/".join(str(trace.iterations_to(t) or "–") for t in TARGETS)

    row = {"mesh": name, "dofs": dofs, "m": problem.num_contact_nodes, "active": num_active}
    actual = {
        "paper r*": {"polish": False, "expert": {"alpha": 1.0, "anderson": 0}},
        "both, no polish": {
            "polish": False,
            "expert": {"alpha": DEFAULT_ALPHA, "anderson": DEFAULT_ANDERSON},
        },
    }
    for label, options in actual.items():
        trace, *_ = run_variant(problem, u_ref, r, options, max_iter=MAX_ITER)
        row[label] = counts(trace)
    operator = PenalisedOperator(problem, "limit_")
    try:
        operator.set_penalty(r)
        for memory in MEMORIES:
            trace = known_active_set_run(problem, operator, u_ref, active, DEFAULT_ALPHA, memory)
            row[f"known 𝒜, Anderson {memory}" if memory else "known 𝒜, plain"] = counts(trace)
    finally:
        operator.destroy()
    say("   " + ", ".join(f"{k} {v}" for k, v in row.items() if k != "mesh"))
    u_ref.destroy()
    problem.destroy()
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the two smallest meshes of each")
    parser.add_argument("--out", default="out_benchmarks")
    args = parser.parse_args()
    sizes, levels = ((32, 64), (0, 1)) if args.quick else ((32, 64, 128, 256), (0, 1, 2, 3))
    meshes = [(f"example1 h=1/{n}", lambda n=n: example1(h=1 / n)) for n in sizes]
    meshes += [(f"example3 level {k}", lambda k=k: example3(level=k)) for k in levels]
    rows = [bench_mesh(name, build()) for name, build in meshes]
    say(f"\niterations to relative error {' / '.join(f'{t:.0e}' for t in TARGETS)} in u")
    write_table(rows, Path(args.out) / "acceleration_limit.csv")


if __name__ == "__main__":
    main()
