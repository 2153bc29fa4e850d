"""labels.csv: hand-labelled tool-tip pixels (``frame,u,v``), for evaluation only.

``frame`` is the 0-based frame index, ``u, v`` the tip pixel in the RAW
(distorted) left image. Frames without a row are unlabelled.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError, read_text

HEADER = ["frame", "u", "v"]


#: how far (px) a label may lie outside the image: labelling slack at the border
BORDER_SLACK_PX = 10.0


def read_labels(path: str | Path, image_size: tuple[int, int] | None = None,
                size_from: str | None = None) -> dict[int, np.ndarray]:
    """Read labels.csv -> {frame: array([u, v]) in px}.

    Rows whose u and v are both empty (or both ``nan``) are unlabelled and
    dropped. Raises InputError naming the file (and line) on a wrong header, a
    non-numeric, infinite or half-missing value, a negative or repeated frame, or, with
    ``image_size`` (height, width), a pixel more than ``BORDER_SLACK_PX``
    outside the image; ``size_from`` names where ``image_size`` came from, for that
    message (a label that would fit the image with width and height swapped blames the
    size, not the label).
    """
    path = Path(path)
    try:
        return _parse_labels(read_text(path), path, image_size, size_from)
    except csv.Error as e:
        raise InputError(f"{path}: not a readable CSV file ({e})") from None


def _parse_labels(text: str, path: Path, image_size, size_from: str | None) -> dict[int, np.ndarray]:
    out: dict[int, np.ndarray] = {}
    reader = csv.reader(text.splitlines())
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
        if np.all(np.isnan(uv)) and all(c.strip().lower() in ("", "nan") for c in row[1:]):
            continue   # both empty or both nan: the tip is not labelled in this frame
        if not np.all(np.isfinite(uv)):
            raise InputError(f"{path}: line {line}: u, v must be finite numbers, got {','.join(row[1:])!r}")
        if image_size is not None:
            h, w = image_size
            if not _inside(uv, w, h):
                raise InputError(_outside_message(path, line, row, w, h, size_from))
        out[frame] = uv
    return out


def _inside(uv: np.ndarray, w: int, h: int) -> bool:
    s = BORDER_SLACK_PX
    return bool(-s <= uv[0] <= w + s and -s <= uv[1] <= h + s)


def _outside_message(path: Path, line: int, row: list[str], w: int, h: int, size_from: str | None) -> str:
    """The error for a label outside the w x h image; one that the h x w image would hold
    points at the size's source (width and height swapped there?)."""
    msg = f"{path}: line {line}: pixel ({row[1].strip()}, {row[2].strip()}) is outside the {w}x{h} image"
    if size_from:
        msg += f" ({size_from})"
        if w != h and _inside(np.array([float(row[1]), float(row[2])]), h, w):
            msg += f"; it lies inside a {h}x{w} image: are width and height swapped in {size_from}?"
    return msg


def write_labels(path: str | Path, labels: dict[int, np.ndarray]) -> None:
    """Write {frame: (u, v) px} as labels.csv, sorted by frame, full precision."""
    with Path(path).open("w", newline="") as f:
        f.write(",".join(HEADER) + "\n")
        for frame in sorted(labels):
            u, v = np.asarray(labels[frame], dtype=float).ravel()[:2]
            f.write(f"{int(frame)},{float(u)!r},{float(v)!r}\n")
