"""Output files that are complete or absent: each is written to a temporary name beside its place
and renamed into it, so a failed or interrupted write never leaves half a file, nor destroys a
good file of the same name."""
from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["atomic_path", "write_text", "write_json", "write_csv", "save_figure", "json_safe"]


class atomic_path:
    """``with atomic_path(path) as tmp:`` write ``tmp``; on success it replaces ``path``, on any
    exception it is removed and ``path`` is left as it was."""

    def __init__(self, path, suffix: str = ""):
        self.path = Path(path)
        self.suffix = suffix or self.path.suffix

    def __enter__(self) -> Path:
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=f".part{self.suffix}",
                                   dir=self.path.parent)
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            os.chmod(self.tmp, 0o644)
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return False


def json_safe(obj):
    """``obj`` with NaN as null and infinities as the strings ``"inf"``/``"-inf"`` (strict
    JSON), numpy scalars as Python numbers."""
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        if math.isnan(obj):
            return None
        if math.isinf(obj):
            return "inf" if obj > 0 else "-inf"
        return obj
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def write_text(path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json(path, obj) -> Path:
    return write_text(path, json.dumps(json_safe(obj), indent=2) + "\n")


def write_csv(path, result: np.ndarray) -> Path:
    """A structured array of float columns as CSV, the columns named in a header: fmpy's format
    (``fmpy.util.write_csv``: quoted names, each number as Python prints it, the shortest text
    that reads back to the same float), written in one block."""
    names = result.dtype.names
    rows = np.column_stack([result[c] for c in names]).tolist() if len(result) else []
    text = ",".join(f'"{n}"' for n in names) + "\n" \
        + "".join(",".join(map(repr, row)) + "\n" for row in rows)
    return write_text(path, text)


def save_figure(fig, path, dpi: int = 110) -> Path:
    """Write a matplotlib Figure as PNG (or the format of the path's suffix)."""
    from .figures import ticks_in_view

    with atomic_path(path) as tmp, ticks_in_view(fig):
        fig.savefig(tmp, dpi=dpi, format=Path(path).suffix.lstrip(".") or "png")
    return Path(path)
