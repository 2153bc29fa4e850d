"""Tip-error metrics against labels.csv (and, when present, truth.csv).

The method's headline number is the 2-D tool-tip error: the distance (px)
between the estimated tip, projected into the RAW (distorted) left image, and
the hand-labelled tip, also reported in % of the image diagonal.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from graphtrack.estimate.base import STD_COLUMNS
from graphtrack.geometry.se3 import invert, matrix_to_bw, rotation_angle_deg
from graphtrack.io.run_output import write_text
from graphtrack.io.trajectory import read_trajectory
from graphtrack.robot.features import base_features


def summary(values: np.ndarray) -> dict:
    """mean, std, median, p95 of finite values (NaN when there are none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return {"mean": float("nan"), "std": float("nan"), "median": float("nan"), "p95": float("nan")}
    return {"mean": float(v.mean()), "std": float(v.std()), "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95))}


def tip_errors(frames: np.ndarray, tips: np.ndarray, labels: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per labelled frame the 2-D tip error (px).

    frames: (F,) frame indices of the trajectory; tips: (F, 2) estimated raw
    tip pixels; labels: frame -> (u, v). Returns (scored frame indices, errors).
    A labelled frame absent from the trajectory (skipped) is not scored.
    """
    index = {int(f): i for i, f in enumerate(frames)}
    scored, errs = [], []
    for f in sorted(labels):
        i = index.get(int(f))
        if i is None or not np.all(np.isfinite(tips[i])):
            continue
        scored.append(int(f))
        errs.append(float(np.linalg.norm(np.asarray(tips[i]) - np.asarray(labels[f]))))
    return np.asarray(scored, dtype=int), np.asarray(errs, dtype=float)


def tip_metrics(frames, tips, labels, diagonal: float, skipped: dict[str, int] | None = None,
                n_frames: int | None = None) -> dict:
    """The metrics.json document: tip error in px and in % of the image diagonal."""
    scored, errs = tip_errors(np.asarray(frames), np.asarray(tips), labels)
    doc = {
        "tip_error_px": summary(errs),
        "tip_error_percent_diagonal": summary(100.0 * errs / diagonal),
        "frames_scored": int(len(scored)),
        "frames_labelled": int(len(labels)),
        "frames_skipped": int(sum((skipped or {}).values())),
        "skipped_reasons": dict(skipped or {}),
        "image_diagonal_px": float(diagonal),
    }
    if n_frames is not None:
        doc["frames_total"] = int(n_frames)
    return doc


# -- accumulated error (the method's Fig. 4) -----------------------------------------
def accumulated_error(errors: np.ndarray) -> np.ndarray:
    """Running mean of the per-frame errors: a_k = (e_1 + ... + e_k) / k.

    Non-finite entries are left out of both the sum and the count (the curve
    holds its last value over them; NaN before the first finite error).
    """
    e = np.asarray(errors, dtype=float).ravel()
    ok = np.isfinite(e)
    s = np.cumsum(np.where(ok, e, 0.0))
    n = np.cumsum(ok)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def tip_error_series(trajectory: dict, labels: dict[int, np.ndarray],
                     diagonal: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(scored frames, per-frame 2-D tip errors) of a read trajectory against labels.

    Errors in px, or in % of the image diagonal when ``diagonal`` is given.
    """
    frames, errs = tip_errors(trajectory["frame"], trajectory["tip"], labels)
    if diagonal:
        errs = 100.0 * errs / float(diagonal)
    return frames, errs


def paired_difference(a: np.ndarray, b: np.ndarray, block: int = 30, resamples: int = 2000,
                      seed: int = 0, level: float = 0.95) -> dict:
    """Mean of d_k = a_k - b_k over the frames both score, with a moving-block
    bootstrap confidence interval.

    a, b: per-frame errors of two estimators on the same frames (same shape,
    same units, NaN where a frame is not scored). Tracking errors persist for
    seconds, so frames are not independent: the bootstrap draws ceil(n /
    block) blocks of ``block`` consecutive differences (30 frames: 1 s at
    30 Hz) with replacement, truncates to n and averages; the interval is the
    central ``level`` percentile range of ``resamples`` such means (``seed``
    fixes the draws). A difference whose interval holds 0 is not decided by the
    data. With fewer than two blocks of shared frames (n < 2 block) the
    blocks cannot show the spread, and the interval is NaN. On strongly
    persistent errors (errors that last many blocks) the interval is too
    narrow: read "decided" as somewhat optimistic. Unscored frames are dropped
    before blocking, so a block may span a gap.
    Returns {"mean", "low", "high", "frames"} (all NaN when no frame is shared).
    """
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    if a.shape != b.shape:
        raise ValueError(f"paired_difference: {len(a)} and {len(b)} frames; the errors must be on the same frames")
    d = a - b
    d = d[np.isfinite(d)]
    n, L = len(d), max(int(block), 1)
    if n == 0:
        return {"mean": float("nan"), "low": float("nan"), "high": float("nan"), "frames": 0}
    if n < 2 * L:
        return {"mean": float(d.mean()), "low": float("nan"), "high": float("nan"), "frames": int(n)}
    starts = np.random.default_rng(seed).integers(0, n - L + 1, size=(int(resamples), -(-n // L)))
    idx = (starts[:, :, None] + np.arange(L)).reshape(int(resamples), -1)[:, :n]
    means = d[idx].mean(axis=1)
    tail = 50.0 * (1.0 - level)
    low, high = np.percentile(means, [tail, 100.0 - tail])
    return {"mean": float(d.mean()), "low": float(low), "high": float(high), "frames": int(n)}


# -- runtime --------------------------------------------------------------------------
def runtime_metrics(ms: np.ndarray) -> dict:
    """Per-frame runtime statistics (ms): mean, std, median, p95, max, and the fps of the median."""
    v = np.asarray(ms, dtype=float)
    v = v[np.isfinite(v)]
    doc = summary(v)
    doc["max"] = float(v.max()) if len(v) else float("nan")
    doc["fps_median"] = float(1e3 / doc["median"]) if len(v) and doc["median"] > 0 else float("nan")
    return doc


# -- against ground truth (truth.csv of simulated recordings) -------------------------
def rotation_error_deg(R_est: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Angle (deg) of R_est R_true^T, for (..., 3, 3) stacks."""
    return rotation_angle_deg(R_est, R_true)


def pose_errors(E_est: np.ndarray, E_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame translation error (mm) and rotation error (deg) of E (..., 4, 4)."""
    E_est, E_true = np.asarray(E_est, float), np.asarray(E_true, float)
    t = 1e3 * np.linalg.norm(E_est[..., :3, 3] - E_true[..., :3, 3], axis=-1)
    return t, rotation_error_deg(E_est[..., :3, :3], E_true[..., :3, :3])


def perturbation(E_true: np.ndarray, E_est: np.ndarray) -> np.ndarray:
    """xi = (b, w) with E_true = Exp(xi) . E_est (left, camera-frame perturbation; translation first).

    Exp is the (b, w) map of :mod:`graphtrack.geometry.se3` (translation b in m,
    axis-angle w in rad).
    """
    return matrix_to_bw(np.asarray(E_true, float) @ invert(np.asarray(E_est, float)))


def nees(E_true: np.ndarray, E_est: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared per frame with a diagonal covariance.

    std: (N, 6) standard deviations of xi (std_bx..std_wz); frames with a
    non-finite or non-positive std get NaN. Consistent filters average 6.
    """
    xi = perturbation(E_true, E_est)
    std = np.asarray(std, float)
    ok = np.all(np.isfinite(std) & (std > 0), axis=-1) & np.all(np.isfinite(xi), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.sum((xi / np.where(std > 0, std, 1.0)) ** 2, axis=-1)
    return np.where(ok, v, np.nan)


#: chi-square(6) two-sided 95% bounds of a single NEES value.
NEES_95 = (1.2373442457912, 14.4493753446378)


def truth_path(recording: str | Path) -> Path | None:
    """truth.csv of a recording folder (or of the folder holding a recording file), if any."""
    p = Path(recording)
    folder = p if p.is_dir() else p.parent
    t = folder / "truth.csv"
    return t if t.is_file() else None


def truth_errors(est: dict, truth: dict, tips_base: dict[int, np.ndarray] | None = None) -> dict:
    """Per-frame errors of a trajectory against truth, on the frames both hold.

    est, truth: :func:`graphtrack.io.trajectory.read_trajectory` dicts.
    tips_base: frame -> tool tip in the PSM base frame from that frame's joint
    READINGS (what the estimator saw); the 3-D tip error is then
    |E_est tip - E_true tip| in mm. When truth holds camera-frame tip columns
    (tip_x, tip_y, tip_z, metres) those are the true tip instead.
    Returns arrays: frame, trans_mm, rot_deg, tip_mm, tip2d_px (against
    truth's tip_u/v), tip_depth_mm and tip_lateral_mm (the 3-D error e = p_est - p_true
    split along the true tip's viewing ray r = p_true / |p_true|: depth e . r, signed,
    positive when the estimate lies beyond the truth; lateral |e - (e . r) r|; so that
    tip_mm^2 = depth^2 + lateral^2) and nees (when est has the std columns).
    """
    ti = {int(f): i for i, f in enumerate(truth["frame"])}
    pairs = [(i, ti[int(f)]) for i, f in enumerate(est["frame"]) if int(f) in ti]
    ie = np.array([p[0] for p in pairs], dtype=int)
    it = np.array([p[1] for p in pairs], dtype=int)
    frames = np.asarray(est["frame"])[ie]
    Ee, Et = est["E"][ie], truth["E"][it]
    trans, rot = pose_errors(Ee, Et)
    out = {"frame": frames, "trans_mm": trans, "rot_deg": rot,
           "tip2d_px": np.linalg.norm(est["tip"][ie] - truth["tip"][it], axis=-1)}
    tip_mm, depth, lateral = (np.full(len(frames), np.nan) for _ in range(3))
    tx = truth.get("extras", {})
    true_cam = None
    if all(k in tx for k in ("tip_x", "tip_y", "tip_z")):
        true_cam = np.stack([tx["tip_x"], tx["tip_y"], tx["tip_z"]], -1)[it]
    if tips_base:
        for k, f in enumerate(frames):
            tb = tips_base.get(int(f))
            if tb is None or not np.all(np.isfinite(tb)):
                continue
            pe = Ee[k, :3, :3] @ tb + Ee[k, :3, 3]
            pt = true_cam[k] if true_cam is not None else Et[k, :3, :3] @ tb + Et[k, :3, 3]
            e, r = 1e3 * (pe - pt), pt / np.linalg.norm(pt)
            tip_mm[k], depth[k] = np.linalg.norm(e), e @ r
            lateral[k] = np.linalg.norm(e - depth[k] * r)
    out.update(tip_mm=tip_mm, tip_depth_mm=depth, tip_lateral_mm=lateral)   # NaN without readings
    ex = est.get("extras", {})
    if all(c in ex for c in STD_COLUMNS):
        std = np.stack([ex[c] for c in STD_COLUMNS], -1)[ie].astype(float)
        out["nees"] = nees(Et, Ee, std)
    return out


def truth_metrics(errors: dict) -> dict:
    """Summaries (mean, std, median, p95) of :func:`truth_errors`' arrays for metrics.json."""
    doc = {"truth_frames": int(len(errors["frame"])),
           "tip_error_3d_mm": summary(errors["tip_mm"]),
           "tip_error_3d_depth_mm": summary(np.abs(errors["tip_depth_mm"])),
           "tip_error_3d_lateral_mm": summary(errors["tip_lateral_mm"]),
           "translation_error_mm": summary(errors["trans_mm"]),
           "rotation_error_deg": summary(errors["rot_deg"]),
           "tip_error_vs_truth_px": summary(errors["tip2d_px"])}
    if "nees" in errors:
        v = errors["nees"]
        fin = v[np.isfinite(v)]
        doc["nees"] = summary(v)
        doc["nees"]["dof"] = 6
        doc["nees"]["fraction_in_95"] = (float(np.mean((fin >= NEES_95[0]) & (fin <= NEES_95[1])))
                                         if len(fin) else float("nan"))
    return doc


def write_errors_csv(path: str | Path, errors: dict) -> None:
    """Per-frame truth errors as CSV (frame, trans_mm, rot_deg, tip_mm, tip2d_px,
    tip_depth_mm, tip_lateral_mm[, nees]), written whole or not at all; InputError naming
    the file when it cannot be written."""
    cols = [c for c in ("trans_mm", "rot_deg", "tip_mm", "tip2d_px", "tip_depth_mm", "tip_lateral_mm", "nees")
            if c in errors]
    lines = [",".join(["frame"] + cols)]
    lines += [",".join([str(int(fr))] + [repr(float(errors[c][k])) for c in cols])
              for k, fr in enumerate(errors["frame"])]
    write_text(path, "\n".join(lines) + "\n")


def check_truth(recording: str | Path) -> None:
    """Read the recording's truth.csv, if any, so that a bad one is refused (InputError
    naming the file, line and frame) before a run rather than after it."""
    tp = truth_path(recording)
    if tp is not None:
        read_trajectory(tp, poses_required=True)


def evaluate_against_truth(recording: str | Path, out: str | Path, robot=None,
                           joints: dict[int, np.ndarray] | None = None) -> dict:
    """What track() adds to metrics.json beyond the label metrics.

    Always: ``runtime_ms`` (per-frame runtime statistics of trajectory.csv's
    ``ms``). When the recording has truth.csv: the truth summaries of
    :func:`truth_metrics`, and the per-frame errors in ``out/truth_errors.csv``.
    robot + joints (frame -> joint vector as read) give the 3-D tip error.
    """
    out = Path(out)
    est = read_trajectory(out / "trajectory.csv")
    doc = {"runtime_ms": runtime_metrics(est["ms"])}
    tp = truth_path(recording)
    if tp is None:
        return doc
    truth = read_trajectory(tp, poses_required=True)
    tips_base = None
    if robot is not None and joints and robot.tool_tip is not None:
        fr = sorted(joints)
        q = np.stack([np.asarray(joints[f], float) for f in fr])
        tips = base_features(robot, q).tip
        tips_base = {f: tips[k] for k, f in enumerate(fr)}
    errs = truth_errors(est, truth, tips_base)
    write_errors_csv(out / "truth_errors.csv", errs)
    doc.update(truth_metrics(errs))
    return doc
