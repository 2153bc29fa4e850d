"""trajectory.csv / trajectory.tum: what tracking writes, row by row.

trajectory.csv (format doc, "What tracking writes") has the header::

    frame,stamp,tx,ty,tz,qx,qy,qz,qw,tip_u,tip_v,ms[,extra columns...]

- ``tx, ty, tz``: translation of the camera-from-base transform E, METRES;
- ``qx, qy, qz, qw``: its rotation as a unit quaternion (x, y, z, w), w >= 0;
- ``tip_u, tip_v``: estimated tool tip in the raw left image, px (``nan`` if none);
- ``ms``: wall-clock milliseconds spent on the frame.

trajectory.tum holds ``stamp tx ty tz qx qy qz qw`` per line (no header), the
TUM RGB-D format that trajectory-evaluation tools (evo, ...) read.

Every row is flushed when written, so an interrupted run keeps all finished
frames. Poses and stamps are written with ``repr`` (shortest exact round trip).
truth.csv (simulator ground truth) uses the same columns; :func:`read_trajectory`
reads both (an empty ``ms`` or tip reads as NaN).
"""
from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from graphtrack.errors import InputError
from graphtrack.geometry.se3 import make_transform, matrix_to_quaternion, quaternion_to_matrix

COLUMNS = ["frame", "stamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw", "tip_u", "tip_v", "ms"]


@dataclass
class TrajectoryRow:
    """One row: frame index, stamp (s), E (4x4, m), tip (u, v) px or None, ms, extras."""

    frame: int
    stamp: float
    E: np.ndarray
    tip_uv: Any = None
    ms: float = float("nan")
    extra: dict = field(default_factory=dict)


def _num(x) -> str:
    x = float(x)
    return repr(x) if math.isfinite(x) else ("nan" if math.isnan(x) else ("inf" if x > 0 else "-inf"))


def _extra(v) -> str:
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(int(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return _num(v)
    return str(v)


def _csv_line(fields: list[str]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(fields)
    return buf.getvalue()


def _pose_fields(E: np.ndarray) -> list[str]:
    E = np.asarray(E, dtype=float)
    if E.shape != (4, 4):
        raise ValueError(f"E must be 4x4, got shape {E.shape}")
    if np.all(np.isfinite(E)):
        q = matrix_to_quaternion(E[:3, :3])
    else:
        q = np.full(4, np.nan)
    return [_num(v) for v in E[:3, 3]] + [_num(v) for v in q]


class TrajectoryWriter:
    """Stream trajectory.csv and trajectory.tum into ``out_dir``, one flushed row per frame.

    Parameters
    ----------
    out_dir : output folder (created if missing); existing trajectory files are replaced.
    extra_columns : names of estimator-specific columns appended after the
        twelve standard ones (e.g. ``["std_bx", ..., "n_features"]``).

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, out_dir: str | Path, extra_columns: Iterable[str] = ()):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.extra_columns = list(extra_columns)
        clash = set(self.extra_columns) & set(COLUMNS)
        if clash or len(set(self.extra_columns)) != len(self.extra_columns):
            raise ValueError(f"extra columns must be unique and not standard ones: {self.extra_columns}")
        self.csv_path = self.out_dir / "trajectory.csv"
        self.tum_path = self.out_dir / "trajectory.tum"
        self.rows_written = 0
        self._csv = self._tum = None
        self._open("w")

    # -- files ----------------------------------------------------------------------
    def _open(self, mode: str, csv_path: Path | None = None, tum_path: Path | None = None) -> None:
        self._paths = (csv_path or self.csv_path, tum_path or self.tum_path)
        try:
            self._csv = self._paths[0].open(mode, newline="", encoding="utf-8")
            self._tum = self._paths[1].open(mode, newline="", encoding="utf-8")
            self._good = [p.stat().st_size for p in self._paths]
        except OSError as e:
            self._fail(e)
        if mode == "w":
            self._emit(_csv_line(COLUMNS + self.extra_columns), "")

    def _emit(self, csv_text: str, tum_text: str) -> None:
        """Append one complete line to each file and flush; on a write error (full disk)
        cut both files back to their last complete line and raise InputError."""
        try:
            self._csv.write(csv_text)
            self._tum.write(tum_text)
            self._csv.flush()
            self._tum.flush()
        except OSError as e:
            self._fail(e)
        self._good[0] += len(csv_text.encode("utf-8"))
        self._good[1] += len(tum_text.encode("utf-8"))

    def _fail(self, e: OSError):
        n = self.rows_written
        for f in (self._csv, self._tum):
            try:
                if f is not None:
                    f.close()   # its flush may fail again; the file is closed all the same
            except OSError:
                pass
        self._csv = self._tum = None
        for path, size in zip(self._paths, getattr(self, "_good", (0, 0))):
            try:
                os.truncate(path, size)
            except OSError:
                pass
        raise InputError(f"{self._paths[0]}: cannot write ({e.strerror or e}); trajectory.csv and "
                         f"trajectory.tum keep the {n} complete rows written before") from None

    def _format(self, frame_index, stamp, E, tip_uv, ms, extra) -> tuple[list[str], str]:
        pose = _pose_fields(E)
        tip = np.full(2, np.nan) if tip_uv is None else np.asarray(tip_uv, dtype=float).ravel()
        if tip.size != 2:
            raise ValueError(f"tip_uv must hold 2 values, got {tip.size}")
        extra = extra or {}
        unknown = set(extra) - set(self.extra_columns)
        if unknown:
            raise ValueError(f"extra values {sorted(unknown)} are not among the declared extra_columns")
        row = ([str(int(frame_index)), _num(stamp)] + pose + [_num(tip[0]), _num(tip[1]), _num(ms)]
               + [_extra(extra.get(c)) for c in self.extra_columns])
        return row, " ".join([_num(stamp)] + pose) + "\n"

    def write(self, frame_index: int, stamp: float, E: np.ndarray, tip_uv=None,
              ms: float = float("nan"), extra: dict | None = None) -> None:
        """Append one frame and flush both files.

        frame_index: 0-based frame; stamp: seconds; E: 4x4 camera-from-base (m);
        tip_uv: (u, v) raw-image px, or None/NaN; ms: wall-clock ms for the frame;
        extra: {column: value} for the declared extra columns (missing ones are empty).
        """
        if self._csv is None:
            raise ValueError("TrajectoryWriter is closed")
        row, tum = self._format(frame_index, stamp, E, tip_uv, ms, extra)
        self._emit(_csv_line(row), tum)
        self.rows_written += 1

    def rewrite_all(self, rows: Iterable) -> None:
        """Replace everything written so far by ``rows`` (offline estimators' refined answers).

        ``rows``: TrajectoryRow objects, dicts with :class:`TrajectoryRow`'s field
        names, or tuples in :meth:`write`'s argument order. Written to temporary
        files and renamed over the old ones, so an interruption leaves either
        the streamed or the refined trajectory, never a mix. Later :meth:`write`
        calls append after the new rows.
        """
        self.close()
        tmp_csv = self.csv_path.with_name(self.csv_path.name + ".tmp")
        tmp_tum = self.tum_path.with_name(self.tum_path.name + ".tmp")
        try:
            self._write_rows(rows, tmp_csv, tmp_tum)
        except InputError:
            for t in (tmp_csv, tmp_tum):   # the streamed files stay as they were
                t.unlink(missing_ok=True)
            raise
        try:
            os.replace(tmp_csv, self.csv_path)
            os.replace(tmp_tum, self.tum_path)
        except OSError as e:
            raise InputError(f"{self.csv_path}: cannot replace ({e.strerror or e})") from None
        self._open("a")

    def _write_rows(self, rows: Iterable, tmp_csv: Path, tmp_tum: Path) -> None:
        self._open("w", tmp_csv, tmp_tum)
        self.rows_written = 0
        for r in rows:
            if isinstance(r, TrajectoryRow):
                args = (r.frame, r.stamp, r.E, r.tip_uv, r.ms, r.extra)
            elif isinstance(r, dict):
                args = (r["frame"], r["stamp"], r["E"], r.get("tip_uv"), r.get("ms", float("nan")),
                        r.get("extra"))
            else:
                args = tuple(r)
            self.write(*args)
        self.close()

    def close(self) -> None:
        files, self._csv, self._tum = (self._csv, self._tum), None, None
        for f in files:
            if f is not None:
                try:
                    f.close()
                except OSError as e:   # rows are flushed one by one: this loses none
                    raise InputError(f"{self.csv_path}: cannot write ({e.strerror or e})") from None

    def __enter__(self) -> "TrajectoryWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _float(s: str) -> float:
    s = s.strip()
    return float(s) if s else float("nan")


def _require_poses(path: Path, pose: np.ndarray, lines: list[int], frames: list[int]) -> None:
    """InputError at the first row whose tx..qw (N, 7) are partly non-finite or whose
    quaternion is not of unit length within 1 %; a row with all seven empty or NaN is an
    unknown pose (not scored)."""
    unknown = np.all(np.isnan(pose), axis=1)
    with np.errstate(invalid="ignore"):
        ok = np.all(np.isfinite(pose), axis=1) & (np.abs(np.linalg.norm(pose[:, 3:], axis=1) - 1.0) <= 0.01)
    bad = ~(ok | unknown)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: line {lines[k]} (frame {frames[k]}): tx..qw must be finite with a unit "
                         f"quaternion ({int(bad.sum())} such rows)")


def read_trajectory(path: str | Path, poses_required: bool = False) -> dict:
    """Read trajectory.csv or truth.csv.

    ``poses_required`` (truth.csv): every row's tx..qw must be finite with a unit
    quaternion (within 1 %), or all empty (an unknown pose), else InputError naming
    the file, line and frame.

    Returns
    -------
    dict with ``frame`` (N,) int, ``stamp`` (N,) s, ``E`` (N, 4, 4) m,
    ``tip`` (N, 2) px (NaN when absent), ``ms`` (N,) (NaN when empty) and
    ``extras``: {column: (N,) float array, or str array when not numeric}.

    Raises InputError naming the file when the first twelve columns are not the
    standard header or a value is not a number.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder; give the file (e.g. {path / 'trajectory.csv'})")
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    with path.open(newline="") as f:
        reader = csv.reader(f)
        header = [h.strip() for h in next(reader, [])]
        if header[: len(COLUMNS)] != COLUMNS:
            raise InputError(f"{path}: header must start with '{','.join(COLUMNS)}', "
                             f"found {','.join(header)!r}")
        extra_names = header[len(COLUMNS):]
        std, extra, lines = [], [], []
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            if len(row) != len(header):
                raise InputError(f"{path}: line {line} has {len(row)} fields, expected {len(header)}")
            try:
                std.append([int(row[0])] + [_float(v) for v in row[1:len(COLUMNS)]])
            except ValueError:
                raise InputError(f"{path}: line {line} holds a value that is not a number") from None
            extra.append(row[len(COLUMNS):])
            lines.append(line)
    a = np.array([r[1:] for r in std], dtype=float).reshape(-1, len(COLUMNS) - 1)
    t, q = a[:, 1:4], a[:, 4:8]
    if poses_required:
        _require_poses(path, a[:, 1:8], lines, [r[0] for r in std])
    R = np.full((len(a), 3, 3), np.nan)
    ok = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0)
    if np.any(ok):
        R[ok] = quaternion_to_matrix(q[ok])
    extras: dict[str, np.ndarray] = {}
    for j, name in enumerate(extra_names):
        col = [r[j] for r in extra]
        try:
            extras[name] = np.array([_float(v) for v in col], dtype=float)
        except ValueError:
            extras[name] = np.array(col, dtype=str)
    return {"frame": np.array([r[0] for r in std], dtype=int), "stamp": a[:, 0],
            "E": make_transform(R, t), "tip": a[:, 8:10], "ms": a[:, 10], "extras": extras}
