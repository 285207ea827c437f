"""What every point-file writer shares: the error it raises, the atomic write and the JSON encoding.

A file is written to a temporary file in the target directory, flushed, fsync'd and moved into place
with ``os.replace``, so a reader never sees a half-written file and a failing writer leaves none
behind. Kept apart from the format modules and their registry so that every writer (and the store,
the CLI) imports it without importing each other.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .schema import POINT_DTYPE, POINT_NAMES

__all__ = ["PointCloudError", "as_points", "atomic_write", "dumps_meta"]


class PointCloudError(ValueError):
    """A point-cloud file cannot be written or read; the message names the file and the problem."""


def _read_umask() -> int:
    # Reading the umask means setting it; do it once, at import, not while worker threads create files.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Yield a binary file in ``path``'s directory; on success fsync and ``os.replace`` it into place.

    On any exception the temporary file is removed and ``path`` is left as it was (absent or old).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            # mkstemp makes the file 0600; a point cloud gets the permissions of any new file
            os.fchmod(f.fileno(), 0o666 & ~_UMASK)
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    # Make the rename itself durable (best effort: not every platform can fsync a directory).
    with contextlib.suppress(OSError):
        dfd = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def as_points(points: np.ndarray) -> np.ndarray:
    arr = np.asarray(points)
    if arr.dtype != POINT_DTYPE:
        if arr.dtype.names is None or set(arr.dtype.names) != set(POINT_NAMES):
            raise PointCloudError(f"points: expected POINT_DTYPE records, got dtype {arr.dtype}")
        arr = arr.astype(POINT_DTYPE)
    return np.ascontiguousarray(arr.reshape(-1))


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, (Path, tuple, set)):
        return str(o) if isinstance(o, Path) else list(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps_meta(meta: dict[str, Any]) -> str:
    return json.dumps(meta, default=_json_default, indent=2, sort_keys=True, allow_nan=False)
