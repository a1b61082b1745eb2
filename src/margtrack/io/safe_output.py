"""Safe output files: checked before any work, written to a temporary file, renamed into place.

Two halves, used by every command and writer that creates a file:

- :func:`check_output` runs *before* the computation: it refuses an output that is one of
  the inputs (``margtrack run x.h5 -o x.h5``), an existing file unless ``force``, and a
  folder that is missing or not writable, each with the fix in the message;
- :func:`atomic_output` wraps the writing: the data goes to ``.{name}.tmp-XXXXXXXX`` in the
  output's own folder (same file system, so the rename is atomic), is flushed to disk
  (``fsync``) and only then replaces the output with :func:`os.replace`. An exception
  removes the temporary file; a crash (``kill -9``, power loss) leaves the previous output
  as it was, at worst next to a stale temporary file.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterable, Iterator
from pathlib import Path

__all__ = ["AtomicFile", "atomic_output", "check_output", "temp_name_prefix"]


def temp_name_prefix(path: str | Path) -> str:
    """The prefix of the temporary files :func:`atomic_output` creates for ``path``."""
    return f".{Path(path).name}.tmp-"


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name the same file (hard and symbolic links included)."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def check_output(
    output: str | Path, inputs: Iterable[str | Path] = (), *, force: bool = False
) -> Path:
    """Check that ``output`` can be written, before anything is computed; return it as a Path.

    Parameters
    ----------
    output : the file to create.
    inputs : the files (or folders) the output is computed from; the output may not be
        one of them, with or without ``force``.
    force : replace an existing output (the CLI's ``--force``); without it an existing
        file is kept and the call raises.

    Raises
    ------
    ValueError : ``output`` is the same file as an input (also through a link), or is an
        input folder itself.
    IsADirectoryError : ``output`` is an existing folder.
    FileExistsError : ``output`` exists and ``force`` is False; the message says it is
        kept and names ``--force`` / ``force=True``.
    FileNotFoundError : the output's folder does not exist.
    NotADirectoryError : the output's "folder" is a file.
    PermissionError : the output's folder is not writable.
    """
    out = Path(output)
    for source in inputs:
        src = Path(source)
        if _same_file(out, src):
            raise ValueError(
                f"output {out} is the input {src}; writing it would destroy the recording: "
                "choose another output file"
            )
    if out.is_dir():
        raise IsADirectoryError(f"output {out} is a folder; give a file name inside it")
    folder = out.parent
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(
            f"cannot write {out}: {folder} is a file, not a folder; choose another output"
        )
    if not folder.is_dir():
        raise FileNotFoundError(
            f"cannot write {out}: folder {folder} does not exist; create it first "
            f"(mkdir -p {folder}) or choose another output"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PermissionError(
            f"cannot write {out}: folder {folder} is not writable; choose another output "
            "folder or fix its permissions"
        )
    if out.exists() and not force:
        from margtrack.errors import with_cli_fix

        raise with_cli_fix(FileExistsError(
            f"output {out} already exists and was kept; pass --force (force=True in Python) "
            "to replace it, or choose another output"
        ), " (force=True in Python)", "")
    return out


def _new_temp(out: Path) -> Path:
    """Create an empty, unique temporary file next to ``out`` (mode 0666 minus the umask)."""
    prefix = temp_name_prefix(out)
    for _ in range(100):
        tmp = out.with_name(prefix + secrets.token_hex(4))
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"cannot create a temporary file next to {out}; clean {prefix}* up")


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Flush the folder entry of the rename (best effort: not every system allows it)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class AtomicFile:
    """A temporary file next to ``path`` that :meth:`commit` renames onto ``path``.

    The object form of :func:`atomic_output`, for writers that stay open across calls
    (:class:`margtrack.io.estimate_writer.EstimateWriter`). ``tmp`` is the temporary path;
    :meth:`commit` flushes it to disk and replaces ``path``; :meth:`discard` removes it.
    """

    def __init__(self, path: str | Path) -> None:
        out = Path(path)
        if not out.parent.is_dir():
            raise FileNotFoundError(f"cannot write {out}: folder {out.parent} does not exist")
        if out.is_dir():
            raise IsADirectoryError(f"cannot write {out}: it is a folder")
        self.path = out
        self.tmp = _new_temp(out)
        self.done = False

    def commit(self) -> None:
        """Flush the temporary file to disk and rename it onto ``path``."""
        if self.done:
            raise ValueError(f"{self.path} was already committed or discarded")
        try:
            _fsync_file(self.tmp)
            os.replace(self.tmp, self.path)
        except BaseException:
            self.discard()
            raise
        self.done = True
        _fsync_folder(self.path.parent)

    def discard(self) -> None:
        """Remove the temporary file; ``path`` stays as it was."""
        self.done = True
        with contextlib.suppress(OSError):
            self.tmp.unlink()


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    Write the whole file to the yielded path (open it, let a library write it, close it)
    inside the ``with`` block. When the block ends normally the file is flushed to disk
    and renamed to ``path`` (replacing an existing file: check that first with
    :func:`check_output`). When it raises, the temporary file is removed and ``path`` is
    left untouched. The folder of ``path`` must exist (``FileNotFoundError`` otherwise).
    """
    target = AtomicFile(path)
    try:
        yield target.tmp
    except BaseException:
        target.discard()
        raise
    target.commit()
