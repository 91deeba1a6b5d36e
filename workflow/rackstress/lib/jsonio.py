"""JSON files written atomically (a reader sees the old file or the new one, never half)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from rackstress.errors import storage_error


def write_json(path: Path, data) -> None:
    """Write JSON atomically: a reader sees the old file or the new one, never half of one."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    text = json.dumps(data, indent=2, default=jsonable) + "\n"
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except OSError as exc:
        # a full disk or a read-only directory: no temporary file left, the old file intact
        try:
            tmp.unlink()
        except OSError:
            pass
        raise storage_error(exc, "write", path) from None


def jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, tuple):
        return list(x)
    raise TypeError(f"not JSON serializable: {type(x)}")
