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
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException:
        with suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def with_suffix(path: str | os.PathLike, suffix: str) -> str:
    """``path`` with ``suffix`` (e.g. ``".zip"``) added when it has none, as SB3 names its files."""
    p = pathlib.Path(path)
    return str(p if p.suffix else p.with_suffix(suffix))
