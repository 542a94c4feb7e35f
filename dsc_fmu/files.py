"""Writing a file atomically with the user's usual permissions."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

__all__ = ["atomic_write"]


def atomic_write(path: Path | str, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a file beside it that ``os.replace`` moves there: never a partial file.

    The file gets the permissions of any new file (``0o666`` less the umask, not ``mkstemp``'s 0600).

    Parameters
    ----------
    path : pathlib.Path or str
        The file to write; missing parent folders are created.
    data : bytes
        The content.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.partial"
    try:
        with open(partial, "xb") as file:
            file.write(data)
        os.replace(partial, path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return path
