"""Files written whole or not at all, and content digests: the bottom layer every writer uses.

Whatever writes to the path that :func:`atomic_target` yields (our code, SB3, matplotlib), an
interrupted or failed write leaves the destination as it was and no temporary file behind.
"""

from __future__ import annotations

import hashlib
import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd


def check_regular(path: str | Path, info: os.stat_result, limit: int, what: str) -> None:
    """``ValueError`` unless ``info`` (``path``'s stat) is a regular file of at most ``limit``
    bytes: a device such as ``/dev/zero`` or a named pipe would never end."""
    if not stat.S_ISREG(info.st_mode):
        raise ValueError(f"{path} is not a regular file (a device, pipe or socket); pass the "
                         f"{what} itself")
    if info.st_size > limit:
        raise ValueError(f"{path} is {info.st_size:,} bytes, more than a {what} may be "
                         f"({limit:,}); pass the right file")


def file_digest(path: str | Path) -> str:
    """sha256 of a file (used to key results on the exact expert checkpoint)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


@contextmanager
def atomic_target(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path``, renamed onto it when the block succeeds.

    Whatever writes to the yielded path (our code, joblib, SB3, matplotlib), an interrupted or
    failed write leaves ``path`` as it was and no temporary file behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=path.suffix, dir=path.parent, prefix=f".{path.name}.")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_target(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(Path(path), text.encode())


def atomic_write_csv(path: str | Path, frame: pd.DataFrame) -> None:
    atomic_write_text(path, frame.to_csv(index=False, lineterminator="\n"))
