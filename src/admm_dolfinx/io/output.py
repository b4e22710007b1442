"""Writing results: only the files a command produces, each whole or not at all.

The rules (the package's guarantee, tested in ``tests/reliability``):

* An output folder is created when the outputs are written (a command refused before
  that creates none) and never removed or emptied: a command writes its own files
  into it and touches nothing else (``--out .`` is safe).
* A set of files appears whole or not at all: it is written into a *staging* folder
  beside its targets, ``.admm-dolfinx-partial-<host>-<pid>-<random>``, and renamed
  onto the final names only once the whole output was written; if one of them cannot
  be published (a folder in the way), none is (:func:`publish`). A file of the same
  name, e.g. from an earlier run, is replaced.
* A run killed while writing (``kill -9``) leaves its staging folder behind; the next
  output written into the same folder removes every such folder whose process is no
  longer alive on this host. Nothing else is ever deleted.
* Files and folders get the permissions the umask allows, as any other program's.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import tempfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

from dolfinx import fem, io
from mpi4py import MPI

from admm_dolfinx._mpi import raise_collectively, run_on_rank0

__all__ = [
    "STAGING_MARK",
    "atomic_file",
    "atomic_path",
    "check_output_folder",
    "output_folder",
    "publish",
    "rank0_write",
    "remove_stale_staging",
    "write_json",
    "write_xdmf",
]

#: What the name of every staging folder starts with.
STAGING_MARK = ".admm-dolfinx-partial-"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _share(path: Path, directory: bool) -> None:
    """Give ``path`` the permissions a plain ``mkdir``/``open`` would (mkdtemp: 0700)."""
    os.chmod(path, (0o777 if directory else 0o666) & ~_umask())


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


def _staging_name() -> str:
    host = socket.gethostname().replace("-", "_") or "host"
    return f"{STAGING_MARK}{host}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def remove_stale_staging(folder: str | os.PathLike) -> list[Path]:
    """Remove the staging folders of killed runs in ``folder``; one process.

    Only entries named ``.admm-dolfinx-partial-<this host>-<pid>-*`` whose process no
    longer exists are removed; anything else is left alone.

    Returns:
        The removed paths.
    """
    root = Path(folder)
    host = socket.gethostname().replace("-", "_") or "host"
    removed: list[Path] = []
    if not root.is_dir():
        return removed
    for entry in root.iterdir():
        if not entry.name.startswith(f"{STAGING_MARK}{host}-"):
            continue
        pid_text = entry.name[len(STAGING_MARK) + len(host) + 1 :].split("-", 1)[0]
        if not pid_text.isdigit() or _alive(int(pid_text)):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def _check_location(final: Path) -> None:
    """Raise unless ``final`` is, or could be created as, a writable folder; creates nothing."""
    if final.exists() and not final.is_dir():
        raise NotADirectoryError(f"{str(final)!r} exists and is not a folder")
    existing = final
    while not existing.exists():  # the nearest ancestor that exists
        if existing.parent == existing:  # pragma: no cover - the root always exists
            break
        existing = existing.parent
    if not existing.is_dir():
        raise NotADirectoryError(f"{str(existing)!r} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PermissionError(f"no write permission in {str(existing)!r}")


def check_output_folder(comm: MPI.Comm, path: str | os.PathLike) -> Path:
    """Check that ``path`` is, or can be created as, a writable folder; collective.

    Called before the work, so that an unwritable ``--out`` fails in a second, not
    after the solve. Nothing is created: a command refused later (a bad option, a
    failed solve) leaves no folder behind.

    Returns:
        The resolved folder.

    Raises:
        OSError: On every rank, naming the path.
    """
    final = Path(path).resolve()
    rank0_write(comm, final, lambda: _check_location(final))
    return final


#: The staging folder's sub-folder that holds the files a publication replaces, until
#: every new file is in place (restored if one cannot be).
_REPLACED = ".replaced"


def _check_replaceable(entries: list[Path], final: Path) -> None:
    """Raise if some new entry cannot replace what is at its name in ``final``."""
    for entry in entries:
        target = final / entry.name
        if not (target.exists() or target.is_symlink()):
            continue
        if target.is_dir() and not target.is_symlink():
            raise IsADirectoryError(
                f"{str(target)!r} is a folder, in the way of the output file {entry.name!r}: "
                "nothing was written. Move or rename it, or choose another --out"
            )
        if entry.is_dir():
            raise FileExistsError(
                f"{str(target)!r} exists, in the way of the output folder {entry.name!r}: "
                "nothing was written. Move or rename it, or choose another --out"
            )


def publish(staging: Path, final: Path) -> None:
    """Move every entry of ``staging`` into ``final``: all of them or none; one process.

    First every target is checked (a folder where a file goes is refused before
    anything moves); then each file that an entry replaces is moved aside into the
    staging folder, and the entry renamed into place. If a rename fails, every entry
    already moved goes back and every replaced file is restored, so ``final`` is as it
    was. Only on success are the replaced files (older files of the same names)
    removed, as a plain overwrite would.

    Args:
        staging: The folder holding the new entries (a sibling of their targets).
        final: The output folder.

    Raises:
        OSError: If some entry cannot be published; ``final`` is then unchanged.
    """
    entries = sorted(e for e in staging.iterdir() if e.name != _REPLACED)
    _check_replaceable(entries, final)
    replaced = staging / _REPLACED
    replaced.mkdir(exist_ok=True)
    done: list[tuple[str, bool]] = []  # (name, whether an older file was moved aside)
    try:
        for entry in entries:
            target = final / entry.name
            had = target.exists() or target.is_symlink()
            if had:
                os.replace(target, replaced / entry.name)
            done.append((entry.name, had))
            os.replace(entry, target)
    except BaseException:
        for name, had in reversed(done):
            target = final / name
            if not (staging / name).exists() and (target.exists() or target.is_symlink()):
                os.replace(target, staging / name)  # the new entry back to staging
            if had:
                os.replace(replaced / name, target)  # the older file back in place
        raise
    shutil.rmtree(replaced, ignore_errors=True)


@contextlib.contextmanager
def output_folder(comm: MPI.Comm, path: str | os.PathLike) -> Iterator[Path]:
    """Write files into ``path`` whole or not at all, touching nothing else; collective.

    Yields a staging folder; the files the block writes there (``staging / name``)
    are published into ``path`` (:func:`publish`: all of them or none) once the block
    has succeeded on every rank. On a failure (on any rank, ``KeyboardInterrupt``
    included) nothing in ``path`` changes and the staging folder is removed.

    Args:
        comm: Communicator whose ranks all write into the folder.
        path: The output folder (created if need be; never removed).

    Yields:
        The staging folder to write into (a sibling of the final files).
    """
    final = check_output_folder(comm, path)

    def create() -> str:
        final.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(final)
        tmp = Path(tempfile.mkdtemp(prefix=_staging_name(), dir=final))
        _share(tmp, directory=True)
        return str(tmp)

    tmp = Path(rank0_write(comm, final, create))
    error: BaseException | None = None
    try:
        yield tmp
    except BaseException as exc:  # KeyboardInterrupt too: every rank leaves together
        error = exc
    try:
        raise_collectively(comm, error, f"Writing the output {str(final)!r}")
        comm.Barrier()  # every rank has written and closed its part
        rank0_write(comm, final, lambda: publish(tmp, final))
    finally:
        if comm.rank == 0 and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


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
    suffix is kept (writers that infer the format from it still work); the name
    carries the staging mark, so a killed run's leftover is removed by the next
    write into the same folder. One process.

    Args:
        path: Final file (its folder is created if need be).

    Yields:
        The temporary file's path.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(target.parent)
    fd, tmp = tempfile.mkstemp(prefix=_staging_name(), suffix=target.suffix, dir=target.parent)
    os.close(fd)
    _share(Path(tmp), directory=False)
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
    """Write Lagrange functions on one mesh to an XDMF file (ParaView); collective.

    XDMF stores a function in the degree of the mesh geometry: on curved (second-order)
    geometry a P1 function is written interpolated into P2, which represents it exactly.

    Args:
        path: ``.xdmf`` file (the ``.h5`` is written beside it).
        functions: Functions on the same mesh.
    """
    msh = functions[0].function_space.mesh
    degree = msh.geometry.cmaps[0].degree
    with io.XDMFFile(msh.comm, str(path), "w") as xdmf:
        xdmf.write_mesh(msh)
        for f in functions:
            xdmf.write_function(_in_geometry_degree(f, degree))


def _in_geometry_degree(f: fem.Function, degree: int) -> fem.Function:
    """``f`` itself, or ``f`` interpolated into Lagrange of the geometry's degree."""
    element = f.function_space.element.basix_element
    if element.degree == degree:
        return f
    shape = f.function_space.value_shape
    space = fem.functionspace(f.function_space.mesh, ("Lagrange", degree, shape))
    out = fem.Function(space, name=f.name)
    out.interpolate(f)
    return out
