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
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

from dolfinx import fem, io
from mpi4py import MPI

from admm_dolfinx._rank0 import run_on_rank0

__all__ = [
    "atomic_directory",
    "atomic_file",
    "atomic_path",
    "rank0_write",
    "write_json",
    "write_xdmf",
]


def rank0_write(comm: MPI.Comm, target: Path, fn: Callable[[], Any]) -> Any:
    """``fn()`` on rank 0, its failure raised on every rank; collective.

    Files and figures are written by rank 0 alone; if that fails (an unwritable path,
    a renderer error), the other ranks must not wait for it at the next collective
    call.

    Args:
        comm: Communicator.
        target: The file or folder being written (named in the error).
        fn: The writing, run on rank 0 only.

    Returns:
        ``fn()``'s value, broadcast.

    Raises:
        OSError: If ``fn`` raised one (the path cannot be written), on every rank.
        RuntimeError: If ``fn`` raised anything else, on every rank.
    """

    def failure(name: str, text: str, is_os_error: bool) -> Exception:
        if is_os_error:
            return OSError(
                f"Cannot write the output {str(target)!r} ({name}: {text}). Choose a "
                "writable location (for instance with --out)."
            )
        return RuntimeError(f"Writing the output {str(target)!r} failed on rank 0: {name}: {text}")

    return run_on_rank0(comm, fn, failure)


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

    def create() -> str:
        final.parent.mkdir(parents=True, exist_ok=True)
        return tempfile.mkdtemp(prefix=f".{final.name}.", dir=final.parent)

    tmp = Path(rank0_write(comm, final, create))
    ok = False
    try:
        yield tmp
        ok = True
    finally:
        ok = comm.allreduce(ok, op=MPI.LAND)
        comm.Barrier()

        def publish() -> None:
            if final.exists():
                shutil.rmtree(final)
            tmp.rename(final)

        if ok:
            rank0_write(comm, final, publish)
        elif comm.rank == 0:
            shutil.rmtree(tmp, ignore_errors=True)
        comm.Barrier()
    if not ok:  # reached by the ranks whose block succeeded while another's failed
        raise RuntimeError(
            f"The output {str(final)!r} was not written: another rank failed while "
            "writing it (its error is reported there)."
        )


def write_json(comm: MPI.Comm, path: str | os.PathLike, data: Mapping[str, Any]) -> None:
    """Write ``data`` as JSON from rank 0, atomically (temporary file + rename); collective.

    Args:
        comm: Communicator.
        path: Output file.
        data: JSON-serialisable mapping.
    """
    target = Path(path)

    def write() -> None:
        with atomic_file(target) as fh:
            json.dump(data, fh, indent=2, sort_keys=True)
            fh.write("\n")

    rank0_write(comm, target, write)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary sibling of ``path`` that replaces it once the block has written it.

    On an error the temporary file is removed and ``path`` is left as it was. The
    suffix is kept (writers that infer the format from it still work). One process.

    Args:
        path: Final file (its folder is created if need be).

    Yields:
        The temporary file's path.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=target.suffix, dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, newline: str | None = None) -> Iterator[IO[str]]:
    """A text file that appears at ``path`` only once the block has written it whole.

    Args:
        path: Final file (see :func:`atomic_path`).
        newline: Passed to :func:`open` (``""`` for the csv module).

    Yields:
        The open temporary file.
    """
    with atomic_path(path) as tmp, open(tmp, "w", newline=newline) as fh:
        yield fh


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
