"""A tracking run's output folder: refusing to mix runs, strict JSON, and the run's verdict.

- :func:`prepare_run_dir`: a folder holding another run's files (``RUN_FILES``) is
  refused unless ``overwrite``, which deletes exactly those files first (other
  files are the user's and are kept), so a new, shorter run never sits beside an
  old run's overlay.mp4 or truth_errors.csv.
- :func:`write_json`: metrics.json as strict JSON (RFC 8259): NaN and infinities
  become ``null``; like every :func:`write_text`, written to a temporary file and
  renamed, so a full disk leaves the old file or none, never half of one.
- :func:`require_tracked`: a run that tracked no frame is an error (exit status 2)
  naming the skip reasons and the first skipped frame, never a silent exit 0;
  :func:`require_tool_in_front`: so is a run whose tool tip was behind the camera in
  every frame, or far outside the image in every frame (naming handeye.yaml).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

from graphtrack.errors import InputError

#: the files a tracking run writes into its output folder
RUN_FILES = ("trajectory.csv", "trajectory.tum", "metrics.json", "overlay.mp4", "truth_errors.csv",
             "trajectory.csv.tmp", "trajectory.tum.tmp", "metrics.json.tmp", "truth_errors.csv.tmp")


def prepare_run_dir(out: str | Path, overwrite: bool = False, files=None) -> Path:
    """Check ``out`` holds no other run's files (``files``, default RUN_FILES: those
    ``track`` writes); with ``overwrite`` delete them.

    Raises InputError ``"<out>: holds another run's files (...); use --overwrite ..."``.
    """
    out = Path(out)
    found = [n for n in (RUN_FILES if files is None else files) if (out / n).exists()] if out.is_dir() else []
    if found and not overwrite:
        raise InputError(f"{out}: holds another run's files ({', '.join(found)}); use --overwrite to "
                         "replace them, or choose another --out")
    for n in found:
        try:
            (out / n).unlink()
        except OSError as e:
            raise InputError(f"{out / n}: cannot remove the previous run's file ({e.strerror or e})") from None
    return out


def outside_recording(out, sequence) -> None:
    """InputError when ``--out`` is the recording folder itself, or inside one of its own
    folders (frames/, frames_right/, a ROS 2 bag): a run's files would land among the
    recording's (and make compare take it as changed). A folder of its own inside the
    recording (SEQ/run) is fine."""
    from graphtrack.io.recording import part_of_recording

    seq, target = Path(sequence).resolve(), Path(out).resolve()
    same = target == seq or (target.exists() and seq.exists() and os.path.samefile(target, seq))
    inside = next((q for q in [target, *target.parents] if q.parent == seq and part_of_recording(q)), None)
    if same or inside is not None:
        where = "the recording folder itself" if same else f"inside the recording's {inside.name}/"
        raise InputError(f"--out {out} is {where}; write the run's files into a folder of their own, "
                         f"e.g. --out {Path(sequence) / 'run'}")


def strict(obj):
    """``obj`` with every non-finite float replaced by None (recursively through dicts,
    lists and tuples; numpy scalars become Python numbers)."""
    if isinstance(obj, dict):
        return {str(k): strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):  # numpy scalar
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(path: str | Path, doc) -> None:
    """Write ``doc`` as strict, indented JSON (NaN/inf -> null), atomically; InputError
    naming the file when it cannot be written (full disk, ...)."""
    write_text(path, json.dumps(strict(doc), indent=2, allow_nan=False) + "\n")


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path`` and rename it over ``path``, so a
    full disk leaves the old file or none, never a cut-off one; InputError naming the
    file when it cannot be written."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.replace(tmp, path)
    except OSError as e:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise InputError(f"{path}: cannot write ({e.strerror or e})") from None


def require_tracked(result: dict, out: str | Path) -> None:
    """InputError when the run tracked no frame: the skip counts and the first skipped
    frame's message (metrics.json ``skip_examples``) say why."""
    if result.get("frames_tracked", 0) > 0:
        return
    reasons = result.get("skipped_reasons") or {}
    n = int(sum(reasons.values()))
    if not n:
        raise InputError(f"no frame was tracked: the recording yielded no frame (see {Path(out) / 'metrics.json'})")
    counts = ", ".join(f"{k}: {v}" for k, v in sorted(reasons.items()))
    examples = result.get("skip_examples") or {}
    first = min(examples.values(), key=lambda m: _frame_of(m)) if examples else ""
    total = result.get("frames_total", n)
    raise InputError(f"no frame was tracked: {n} of {total} frames skipped ({counts}); first: {first}")


def require_tool_in_front(result: dict, handeye: str | Path) -> None:
    """InputError naming ``handeye`` (the recording's handeye.yaml) when frames were
    tracked but the tool tip lies behind the camera in every one of them (metrics.json
    ``frames_tip_in_front`` = 0): nothing of the tool was in view to track. Usually an
    inverted or mis-signed calibration; else a tool retracted behind the camera throughout.
    So is a run whose tip projected more than an image diagonal outside the image in every
    frame (``frames_tip_near_image`` = 0): a tool in view has its tip nearer than that."""
    n = result.get("frames_tracked", 0)
    front = result.get("frames_tip_in_front")
    if n > 0 and front and result.get("frames_tip_near_image") == 0:
        where = (f"all {n} tracked frames" if front == n
                 else f"all {front} tracked frames with it in front of the camera")
        raise InputError(f"{handeye}: at this hand-eye the tool tip projects more than an image diagonal "
                         f"outside the image in {where}, so nothing in view could be tracked; "
                         "check that the file maps the arm's base into the camera (X_camera = R(rvec) X_base "
                         "+ tvec, tvec in millimetres), not the camera into the base, and that its key prefix "
                         "names the recorded arm (or K1 and D1 in camera_calibration.yaml, which project it)")
    if n > 0 and front == 0:
        raise InputError(f"{handeye}: at this hand-eye the tool tip is behind the camera in all {n} tracked "
                         "frames, so nothing in view could be tracked; the file must map the arm's base into "
                         "the camera (X_camera = R(rvec) X_base + tvec, tvec in millimetres), not the camera "
                         "into the base (or the tool stayed retracted behind the camera throughout)")


def _frame_of(message: str) -> int:
    try:
        return int(message.split(":", 1)[0].split()[-1])
    except (ValueError, IndexError):
        return 1 << 62
