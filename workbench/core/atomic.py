"""Atomic output: a file is either written whole or not at all.

Outputs go to a temporary file in the destination folder and are renamed over
the destination only once complete, so a killed run leaves no partial output.
Writing over a file that is an input of the same run, or to a path that cannot
be written, is refused before the work (:func:`check_output`).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from workbench.core.errors import InputError


def check_output(
    out: str | os.PathLike,
    inputs: Iterable[str | os.PathLike | None] = (),
    *,
    folder: bool = False,
    what: str = "output",
) -> None:
    """Refuse, before any work, an output path that cannot be written.

    Every command that writes calls this for each output before it reads its
    inputs or computes anything, so that a long run never ends in an error
    about its output. Refused (:class:`InputError`, one line):

    - a path that names one of the run's input files;
    - a file output that is an existing folder, or a folder output that is an
      existing file;
    - a parent that is a file (``results.npz/plot.png``), or a folder that does
      not exist and cannot be made (its nearest existing ancestor is a file or
      not writable);
    - an existing file or folder that is not writable.

    Parameters
    ----------
    out : path
        The output file (or folder, with ``folder=True``).
    inputs : iterable of paths
        The run's input files (None entries skipped).
    folder : bool
        ``out`` is a folder the command writes files into (``--plots DIR``).
    what : str
        The option's name for the message (e.g. ``--json``).
    """
    out_path = Path(out)
    resolved = out_path.resolve()
    for item in inputs:
        if item is None:
            continue
        if Path(item).resolve() == resolved:
            raise InputError(f"{out}: refusing to write the output over an input file")
    label = f"{what} {out}" if what != "output" else str(out)
    if resolved.exists():
        if folder and not resolved.is_dir():
            raise InputError(f"{label}: expected a folder to write into, got an existing file")
        if not folder and resolved.is_dir():
            raise InputError(f"{label}: expected a file to write, got an existing folder")
        if not folder and not os.access(resolved, os.W_OK):
            raise InputError(f"{label}: no permission to write it")
        _probe(resolved if folder else resolved.parent, label)
        return
    # the nearest existing ancestor decides whether the missing folders can be made
    parent = resolved.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(
            f"{label}: cannot be written, {parent} is a file, not a folder"
            + ("" if parent == resolved.parent else " (the folders under it cannot be made)")
        )
    _probe(parent, label)


def _probe(folder: Path, label: str) -> None:
    """Create and remove a file in ``folder``: os.access says yes to root on a read-only mount."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".workbench-probe.", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(
            f"{label}: cannot be written in {folder} ({exc.strerror or type(exc).__name__})"
        ) from None


def check_not_input(out: str | os.PathLike, inputs: Iterable[str | os.PathLike | None]) -> None:
    """Refuse an output path that names an input or cannot be written (:func:`check_output`)."""
    check_output(out, inputs)


def _umask() -> int:
    """The process's umask (read by setting and restoring it: the OS offers no getter)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The temporary file keeps ``path``'s suffix (``np.savez`` and matplotlib pick
    the format from it). On any exception, including KeyboardInterrupt, the
    temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    folder.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if suffix is None else suffix
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp" + suffix, dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp makes the file 0600; a result is meant to be shared as any file the
        # user writes: the mode open() would give under the process's umask
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def save_npz(path: str | os.PathLike, **arrays) -> None:
    """``np.savez`` to ``path`` atomically (the file name is kept as given)."""
    import numpy as np

    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
