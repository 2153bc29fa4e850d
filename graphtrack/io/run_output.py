"""A tracking run's output folder: refusing to mix runs, strict JSON, and the run's verdict.

- :func:`prepare_run_dir`: a folder holding another run's files (``RUN_FILES``) is
  refused unless ``overwrite``, which deletes exactly those files first (other
  files are the user's and are kept), so a new, shorter run never sits beside an
  old run's overlay.mp4 or truth_errors.csv; a study's folder (study.json) is refused.
  :func:`refuse_other_runs`: a study's folder holds no track, refine or detect run.
- :func:`write_json`: metrics.json as strict JSON (RFC 8259): NaN and infinities
  become ``null``; like every :func:`write_text`, written to a temporary file and
  renamed, so a full disk leaves the old file or none, never half of one.
- :func:`require_tracked`: a run that tracked no frame is an error (exit status 2)
  naming the skip reasons and the first skipped frame, never a silent exit 0;
  :func:`require_tool_in_front`: so is a run whose tool tip was behind the camera in
  every frame, or far outside the image in every frame (naming handeye.yaml);
  :func:`require_lock`: so is a run whose estimator re-started from a global search on
  half or more of the frames with detections (:func:`lock_problem`: the warning from a
  tenth). :func:`unexplained_problem`: the warning for a run whose predictions explained
  under 15 % of its frames with detections (a tool occluded throughout, or a
  calibration off by more than the hand-eye prior: the estimate never reached the tool).
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import threading
from pathlib import Path

from graphtrack.errors import InputError, is_whole

#: the files a tracking run writes into its output folder
RUN_FILES = ("trajectory.csv", "trajectory.tum", "metrics.json", "overlay.mp4", "overlay.refined.mp4",
             "truth_errors.csv",
             "trajectory.csv.tmp", "trajectory.tum.tmp", "metrics.json.tmp", "truth_errors.csv.tmp")


#: the files ``graphtrack detect`` writes into its output folder
DETECT_FILES = ("detections.csv", "detections_right.csv", "detections.mp4")


@contextlib.contextmanager
def deferred_interrupts():
    """Ctrl-C and SIGTERM held back until the block ends, then handled as they would have
    been (KeyboardInterrupt), so that a frame's outputs are written together or not at all:
    an interrupted run's video holds the frames trajectory.csv has rows for. The Python
    handlers are swapped (a thread mask would not do: the signal goes to any thread that
    does not block it). Does nothing off the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    kinds = (signal.SIGINT, signal.SIGTERM)
    old = {k: signal.signal(k, lambda signum, frame: held.append(signum)) for k in kinds}
    try:
        yield
    finally:
        for k, handler in old.items():
            signal.signal(k, handler)
        if held:
            handler = old[held[0]]
            if callable(handler):
                handler(held[0], None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(held[0])


def check_run_arguments(out, max_frames) -> None:
    """InputError for what the command line's parser refuses, for a caller in Python too: an
    empty output path (it would mean the current folder), a ``max_frames`` that is not a whole
    number of at least 1 (None: all frames)."""
    if not str(out).strip():
        raise InputError("the output folder is an empty path, which would mean the current folder: name the output")
    if max_frames is not None and not (is_whole(max_frames) and max_frames >= 1):
        raise InputError(f"--max-frames must be a whole number of at least 1, got {max_frames!r}")


def _present(out: Path, names) -> list[str]:
    """Which of the file ``names`` a folder ``out`` holds ([] when it is no folder)."""
    return [n for n in names if (out / n).exists()] if out.is_dir() else []


def refuse_other_runs(out: str | Path, what: str) -> None:
    """InputError when ``out`` holds a ``track``/``refine`` or ``detect`` run's files: a
    folder of ``what`` (a study) is its own, and is not mixed with another command's."""
    out = Path(out)
    found = _present(out, RUN_FILES + DETECT_FILES)
    if found:
        raise InputError(f"{out}: holds another command's run ({', '.join(found)}); a {what} folder is its "
                         "own: choose another --out")


def prepare_run_dir(out: str | Path, overwrite: bool = False, files=None) -> Path:
    """Check ``out`` holds no other run's files (``files``, default RUN_FILES: those
    ``track`` writes); with ``overwrite`` delete them.

    Raises InputError ``"<out>: holds another run's files (...); use --overwrite ..."``.
    """
    out = Path(out)
    if (out / "study.json").is_file():
        raise InputError(f"{out}: holds a study (study.json, from compare or demo); choose another --out")
    found = _present(out, RUN_FILES if files is None else files)
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


#: an estimator's starts (searches adopted, the first included) per frame with detections
#: above which its lock is reported as not holding (warning) and the run refused (exit 2).
#: On the 200 randomized tuning recordings (occlusions, the tool leaving the view) the
#: smoother and the particle filter start at most twice in 90-150 frames (0.02);
#: docs/decisions/plausible-inputs.md.
LOCK_WARN, LOCK_REFUSE = 0.1, 0.5
#: fewer starts than this are never reported: a start-up and a re-acquisition or two
LOCK_MIN_STARTS = 3


def _policy_count(result: dict, key: str) -> int:
    """A count of the re-initialisation policy in a run's metrics (``estimator_report``; the
    batch's online smoother's under ``online``), 0 without one."""
    report = result.get("estimator_report") or {}
    report = report.get("online", report) if isinstance(report, dict) else {}
    value = report.get(key) if isinstance(report, dict) else None
    return int(value) if isinstance(value, (int, float)) else 0


def lock_starts(result: dict) -> tuple[int, int]:
    """(starts, frames with detections) of a run's metrics: the searches its estimator adopted
    (``estimator_report`` ``adopted``; the batch's online smoother's), 0 without a search."""
    return _policy_count(result, "adopted"), int(result.get("frames_with_detections") or 0)


def lock_problem(result: dict, recording: str | Path) -> str | None:
    """The warning for a run whose estimator started over from a global search on more than
    LOCK_WARN of its frames with detections (at least LOCK_MIN_STARTS times), None otherwise:
    no pose near the hand-eye prior explained the images from one frame to the next (a
    camera, hand-eye, tool or stereo calibration that does not describe the recording)."""
    starts, n = lock_starts(result)
    if starts < LOCK_MIN_STARTS or starts <= LOCK_WARN * n:
        return None
    text = (f"{recording}: the estimator started over from a global search {starts} times in {n} frames with "
            f"detections (a lock that holds starts once or twice per recording): no pose near the hand-eye "
            f"prior explains the images from one frame to the next, so the estimates are not to be trusted; "
            f"check camera_calibration.yaml (K1, D1), handeye.yaml and robot.json's tool; a handeye.yaml "
            f"known to be far off (beyond about 10 mm / 5 deg) needs a wider prior: --handeye-sigma MM,DEG")
    if result.get("stereo"):
        text += ("; with both images: if --mono tracks steadily, camera_calibration.yaml's R and T, or which "
                 "images are the left ones (frames/ and frames_right/, or the image topics), are wrong")
    return text


def lock_refused(result: dict) -> bool:
    """The estimator started over on at least LOCK_REFUSE of the frames with detections."""
    starts, n = lock_starts(result)
    return starts >= LOCK_MIN_STARTS and starts >= LOCK_REFUSE * n


def require_lock(result: dict, recording: str | Path) -> None:
    """InputError with :func:`lock_problem`'s text when :func:`lock_refused`: nothing was
    tracked from one frame to the next."""
    if lock_refused(result):
        raise InputError(f"nothing was tracked from frame to frame: {lock_problem(result, recording)}")


#: frames the prediction explained (``estimator_report`` ``frames_explained``: misfit at most
#: the divergence monitor's 0.5), as a fraction of the frames it scored (``frames_judged``),
#: under which a run is warned about. On 64 randomized probe recordings (occlusions, the tool
#: leaving the view; hand-eye errors as drawn) the smoother's and the particle filter's
#: lowest was 0.21 (a second instrument over 81 % of the shaft for 52 of 90 frames); runs
#: 25 mm / 10 deg off that never left handeye.yaml explained 0-0.07
#: (docs/decisions/handeye-sigma.md)
EXPLAINED_WARN = 0.15
#: fewer frames judged than this are never reported
EXPLAINED_MIN_FRAMES = 10


def unexplained_problem(result: dict, recording: str | Path) -> str | None:
    """The warning for a run whose estimator's prediction explained fewer than EXPLAINED_WARN
    of the frames it judged (at least EXPLAINED_MIN_FRAMES), None otherwise: the detections lay
    away from the tool the estimate projected on most frames, so the images did not confirm it."""
    judged, explained = _policy_count(result, "frames_judged"), _policy_count(result, "frames_explained")
    if judged < EXPLAINED_MIN_FRAMES or explained >= EXPLAINED_WARN * judged:
        return None
    return (f"{recording}: the estimate explained the detections on {explained} of the {judged} frames it "
            f"judged (a tracked tool explains most of them): the detected edges and markers lay away from the "
            f"tool it projects, so the images did not confirm the estimates; unless the tool was occluded for "
            f"most of the recording, handeye.yaml is off by more than the hand-eye prior allows for (track "
            f"again with --handeye-sigma MM,DEG, e.g. 12,5 for about 25 mm / 10 deg off; "
            f"docs/decisions/handeye-sigma.md), or check camera_calibration.yaml (K1, D1) and robot.json's tool")
