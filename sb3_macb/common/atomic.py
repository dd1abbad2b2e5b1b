"""Files that are replaced whole or not at all: written to a temporary file beside the target, then renamed."""

import os
import pathlib
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from typing import BinaryIO


@contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """
    Open a temporary file in ``path``'s folder for writing (binary); when the block ends without an error, flush it
    to disk and rename it to ``path``. A process killed at any moment leaves either the previous ``path`` or the
    new one, never a part-written file (``os.replace`` is atomic on POSIX and Windows within one file system).

    :param path: The file to (re)write; its folder is created if needed.
    """
    path = os.fspath(path)
    folder = os.path.dirname(path) or "."
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=TMP_SUFFIX, dir=folder)
    except OSError as exc:
        raise AtomicWriteError(path, exc) from None
    try:
        with os.fdopen(fd, "wb") as file:
            os.fchmod(file.fileno(), 0o666 & ~_umask())  # the mode an ordinary open() gives (mkstemp's is 0600)
            try:
                yield file
                file.flush()
                os.fsync(file.fileno())
            except AtomicWriteError:  # (a nested atomic write names its own file)
                raise
            except OSError as exc:
                raise AtomicWriteError(path, exc) from None
        os.replace(tmp, path)
    except BaseException:
        with suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


TMP_SUFFIX = ".tmp"


class AtomicWriteError(OSError):
    """Writing ``path`` failed (e.g. a full disk); the previous file, if any, is unchanged and nothing is left behind."""

    def __init__(self, path: str, cause: OSError):
        super().__init__(cause.errno, f"cannot write {path}: {cause.strerror or cause}", path)

    def __str__(self) -> str:
        return str(self.strerror)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def remove_leftovers(folder: str | os.PathLike) -> list[str]:
    """
    Delete the temporary files and folders (``.NAME.*.tmp``) that a process killed while writing left in ``folder``
    (not recursively); return their names. Only names of that form are touched.

    :param folder: A folder written with :func:`atomic_write` (a missing folder has none).
    """
    import shutil

    removed = []
    with suppress(FileNotFoundError, NotADirectoryError):
        for entry in os.scandir(os.fspath(folder)):
            if entry.name.startswith(".") and entry.name.endswith(TMP_SUFFIX):
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(entry.path, ignore_errors=True)
                else:
                    with suppress(FileNotFoundError):
                        os.unlink(entry.path)
                removed.append(entry.name)
    return removed


def with_suffix(path: str | os.PathLike, suffix: str) -> str:
    """``path`` with ``suffix`` (e.g. ``".zip"``) added when it has none, as SB3 names its files."""
    p = pathlib.Path(path)
    return str(p if p.suffix else p.with_suffix(suffix))
