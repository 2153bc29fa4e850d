"""labels.csv: hand-labelled tool-tip pixels (``frame,u,v``), for evaluation only.

``frame`` is the 0-based frame index, ``u, v`` the tip pixel in the RAW
(distorted) left image. Frames without a row are unlabelled.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError

HEADER = ["frame", "u", "v"]


def read_labels(path: str | Path) -> dict[int, np.ndarray]:
    """Read labels.csv -> {frame: array([u, v]) in px}.

    Rows whose u or v is empty or NaN are treated as unlabelled and dropped.
    Raises InputError naming the file (and line) on a wrong header, a
    non-numeric value, a negative or repeated frame.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    out: dict[int, np.ndarray] = {}
    with path.open(newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header is None or [h.strip() for h in header] != HEADER:
            raise InputError(f"{path}: header must be 'frame,u,v', found {','.join(header or [])!r}")
        for line, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != 3:
                raise InputError(f"{path}: line {line} has {len(row)} fields, expected 3")
            try:
                frame = int(row[0])
                uv = np.array([float(row[1]) if row[1].strip() else np.nan,
                               float(row[2]) if row[2].strip() else np.nan])
            except ValueError:
                raise InputError(f"{path}: line {line} is not 'frame,u,v' numbers: {','.join(row)!r}") from None
            if frame < 0:
                raise InputError(f"{path}: line {line}: negative frame {frame}")
            if frame in out:
                raise InputError(f"{path}: line {line}: frame {frame} labelled twice")
            if np.all(np.isfinite(uv)):
                out[frame] = uv
    return out


def write_labels(path: str | Path, labels: dict[int, np.ndarray]) -> None:
    """Write {frame: (u, v) px} as labels.csv, sorted by frame, full precision."""
    with Path(path).open("w", newline="") as f:
        f.write(",".join(HEADER) + "\n")
        for frame in sorted(labels):
            u, v = np.asarray(labels[frame], dtype=float).ravel()[:2]
            f.write(f"{int(frame)},{float(u)!r},{float(v)!r}\n")
