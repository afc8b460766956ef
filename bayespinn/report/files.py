"""Atomic file writes for reports: a temporary file in the same folder, renamed into place.

Unlike `tempfile.mkstemp` (always mode 0600) the file is created with `open(..., 'xb')`, so it gets
the usual permissions under the user's umask: reports are meant to be shared.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write `data` to `path` atomically; no half-written file is ever left behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "xb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_text(path: str | Path, text: str) -> Path:
    """UTF-8 text, written atomically."""
    return write_bytes(path, text.encode("utf-8"))
