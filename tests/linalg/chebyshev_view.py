"""What a KSP's view says of its multigrid's Chebyshev smoothers (petsc4py has no getter)."""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

from petsc4py import PETSc


@dataclass(frozen=True)
class ChebyshevLevel:
    """One Chebyshev level as viewed: how its bounds were found, the largest eigenvalue,
    the factor that widened it (None where provided), and the estimator's CG steps."""

    how: str
    largest: float
    widening: float | None
    steps: int | None


def chebyshev_levels(ksp: PETSc.KSP, name: str) -> list[ChebyshevLevel]:
    """The Chebyshev levels of ``ksp``'s multigrid, finest last; collective."""
    comm = ksp.getComm().tompi4py()
    path = comm.bcast(str(Path(tempfile.mkdtemp()) / f"{name}.txt") if comm.rank == 0 else None)
    viewer = PETSc.Viewer().createASCII(path, comm=comm)
    ksp.view(viewer)
    viewer.destroy()
    comm.barrier()
    text = Path(path).read_text()
    levels = []
    for block in re.split(r"KSP Object: \(\w*mg_levels_\d+_\)", text)[1:]:
        found = re.search(
            r"eigenvalues (provided|estimated via \w+)\W+min [-\d.e+]+, max ([-\d.e+]+)", block
        )
        if found is None:
            continue
        widening = re.search(r"with transform: \[[^;]*;\s*[-\d.e+]+\s+([-\d.e+]+)\]", block)
        steps = re.search(r"esteig_\) .*?\n\s+type: cg\n\s+maximum iterations=(\d+)", block)
        levels.append(
            ChebyshevLevel(
                how=found.group(1),
                largest=float(found.group(2)),
                widening=float(widening.group(1)) if widening else None,
                steps=int(steps.group(1)) if steps else None,
            )
        )
    return levels
