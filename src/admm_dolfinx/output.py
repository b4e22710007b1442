"""Writing results: whole or not at all.

Every writer here produces its files in a temporary sibling folder (or file) and
moves them into place only after everything was written, so an interrupted run
never leaves a half-written output behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from dolfinx import fem, io
from mpi4py import MPI

__all__ = ["atomic_directory", "write_json", "write_xdmf"]


@contextlib.contextmanager
def atomic_directory(comm: MPI.Comm, path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder that replaces ``path`` only if the block succeeds; collective.

    Args:
        comm: Communicator whose ranks all write into the folder.
        path: Final folder.

    Yields:
        The temporary folder to write into.
    """
    final = Path(path).resolve()
    tmp = None
    if comm.rank == 0:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=f".{final.name}.", dir=final.parent)
    tmp = Path(comm.bcast(tmp, root=0))
    ok = False
    try:
        yield tmp
        ok = True
    finally:
        ok = comm.allreduce(ok, op=MPI.LAND)
        comm.Barrier()
        if comm.rank == 0:
            if ok:
                if final.exists():
                    shutil.rmtree(final)
                tmp.rename(final)
            else:
                shutil.rmtree(tmp, ignore_errors=True)
        comm.Barrier()


def write_json(comm: MPI.Comm, path: str | os.PathLike, data: Mapping[str, Any]) -> None:
    """Write ``data`` as JSON from rank 0, atomically (temporary file + rename); collective.

    Args:
        comm: Communicator.
        path: Output file.
        data: JSON-serialisable mapping.
    """
    if comm.rank == 0:
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(data, fh, indent=2, sort_keys=True)
                fh.write("\n")
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    comm.Barrier()


def write_xdmf(path: str | os.PathLike, functions: list[fem.Function]) -> None:
    """Write P1 functions on one mesh to an XDMF file (ParaView); collective.

    Args:
        path: ``.xdmf`` file (the ``.h5`` is written beside it).
        functions: Functions on the same mesh.
    """
    msh = functions[0].function_space.mesh
    with io.XDMFFile(msh.comm, str(path), "w") as xdmf:
        xdmf.write_mesh(msh)
        for f in functions:
            xdmf.write_function(f)
