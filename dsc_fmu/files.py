"""Writing a file atomically with the user's usual permissions."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

__all__ = []  # ``atomic_write`` serves the package's writers


def atomic_write(path: Path | str, data: bytes) -> Path:
    """Write ``data`` to ``path`` (its missing folders created) through a file beside it that ``os.replace`` moves
    there: never a partial file. The file gets the permissions of any new file (``0o666`` less the umask, not
    ``mkstemp``'s 0600).
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
