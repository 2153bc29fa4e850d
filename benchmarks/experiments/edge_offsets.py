"""Where the learned detector's shaft edges lie against the true limbs, and what that does to
the online estimators' start-ups (issue #18; docs/decisions/shaded-limbs.md).

For each randomized recording (``graphtrack simulate --randomize``), every ``--every``-th frame
of frames 0..``--frames``: the detector runs on the raw frame as tracking runs it, gated with
the true limb lines, and each associated edge's signed offset from its true limb is the mean
pixel_residual of the segment at 10, 50 and 90 % of its length (+ inwards, into the shaft's
image), tagged refined (moved onto the image edge by the sub-pixel refinement) or band (the
heatmap's band, left as detected). A recording is then

- ``refined inward``: its refined edges' median offset > ``--inward`` px;
- ``mostly bands``: more band edges than refined ones;
- ``clean``: the rest;

and, given a robustness study folder (benchmarks/.data/robustness/<study>, cells as
bench_robustness.py writes them), the fraction of each class whose start-up converged within
15 frames, per estimator. Truth is read here for evaluation only.

    python3 benchmarks/experiments/edge_offsets.py --seeds 700000 700199 --study exp-smbase --estimator smoother
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_robustness as br  # noqa: E402
from graphtrack.detect.base import detect_raw  # noqa: E402
from graphtrack.detect.learned import LearnedDetector  # noqa: E402
from graphtrack.eval.robustness import recording_figures  # noqa: E402
from graphtrack.geometry.lines import pixel_residual  # noqa: E402
from graphtrack.io.recording import open_recording  # noqa: E402
from graphtrack.io.trajectory import read_trajectory  # noqa: E402
from graphtrack.robot.features import base_features, shaft_lines  # noqa: E402
from graphtrack.threads import limit_threads  # noqa: E402


def signed_offset(segment: np.ndarray, rho: np.ndarray, theta: np.ndarray) -> tuple[int, float]:
    """(limb index, px): the segment's mean offset from its nearest true limb, + into the shaft."""
    a, b = segment[:2], segment[2:]
    pts = np.stack([a + f * (b - a) for f in (0.1, 0.5, 0.9)])
    r = [pixel_residual(pts, rho[j], theta[j]).mean() for j in range(2)]
    j = int(np.argmin(np.abs(r)))
    o = 1 - j
    inside = rho[o] * np.array([np.cos(theta[o]), np.sin(theta[o])])    # a point of the other limb
    return j, float(r[j] * np.sign(pixel_residual(inside[None], rho[j], theta[j])[0]))


def recording_offsets(path: Path, detector, frames: int, every: int) -> list[tuple[int, int, bool, float]]:
    """(frame, limb, refined, signed offset px) of every associated edge on the frames looked at."""
    rec = open_recording(path)
    cam = rec.calibration.left
    truth = read_trajectory(path / "truth.csv", poses_required=True)
    row = {int(f): i for i, f in enumerate(truth["frame"])}
    out = []
    for fr in rec.frames(right=False):
        if fr.index > frames:
            break
        if fr.index % every or fr.index not in row:
            continue
        feats = base_features(rec.robot, fr.q).transformed(truth["E"][row[fr.index]])
        rho, theta, valid = shaft_lines(feats, cam.K)
        if not valid:
            continue
        rho, theta = np.ravel(rho), np.ravel(theta)
        det = detect_raw(detector, fr.image, cam, np.stack([rho, theta], -1))
        for seg, refined in zip(det.shaft_segments, det.refined):
            j, off = signed_offset(seg, rho, theta)
            if abs(off) < 10:                      # a line 10 px off is another edge, not a biased one
                out.append((fr.index, j, bool(refined), off))
    return out


def classify(rows, inward: float) -> str:
    refined = [o for _, _, r, o in rows if r]
    bands = [o for _, _, r, o in rows if not r]
    if len(refined) >= 4 and np.median(refined) > inward:
        return "refined inward"
    return "mostly bands" if len(bands) > len(refined) else "clean"


def converged(study: Path, name: str, estimator: str) -> bool | None:
    """The start-up converged within 15 frames (None: not judged or no cell)."""
    runs = study / "runs" / name
    try:
        err = br.tip_errors(br.cell_dir(runs, estimator))
        kin = br.tip_errors(br.cell_dir(runs, "kinematics"))
    except (FileNotFoundError, OSError):
        return None
    if err is None or kin is None:
        return None
    n = min(len(err), len(kin))
    f = recording_figures(err[:n], kin[:n], br.disturbances(br.DATA / "recordings" / name))
    return bool(f["startup_frames"] <= br.LIMIT) if br._judged(f["startup_frames"], f["startup_segment"]) else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=(700000, 700199), help="first and last seed")
    ap.add_argument("--frames", type=int, default=15, help="look at frames 0..N")
    ap.add_argument("--every", type=int, default=3, help="every k-th frame")
    ap.add_argument("--inward", type=float, default=1.0, help="px: the refined edges' median offset called inward")
    ap.add_argument("--study", default=None, help="a study folder under benchmarks/.data/robustness")
    ap.add_argument("--estimator", action="append", default=None, help="cells to judge (pf, smoother, batch)")
    a = ap.parse_args(argv)
    limit_threads(1)
    detector = LearnedDetector()
    paths = sorted(p for p in (br.DATA / "recordings").iterdir()
                   if p.is_dir() and a.seeds[0] <= int(p.name.rsplit("-", 1)[-1]) <= a.seeds[1])
    classes, medians = {}, []
    for p in paths:
        rows = recording_offsets(p, detector, a.frames, a.every)
        refined = [o for _, _, r, o in rows if r]
        if refined:
            medians.append(float(np.median(refined)))
        classes[p.name] = classify(rows, a.inward)
    m = np.array(medians)
    print(f"{len(paths)} recordings; refined edges' median offset per recording: p50 {np.median(m):+.2f}, "
          f"p90 {np.percentile(m, 90):+.2f} px, > {a.inward} px inwards on {int(np.sum(m > a.inward))}")
    for est in a.estimator or ([] if a.study is None else ["pf", "smoother"]):
        for c in ("clean", "mostly bands", "refined inward"):
            judged = [(n, converged(br.DATA / a.study, n, est)) for n, k in classes.items() if k == c]
            judged = [(n, ok) for n, ok in judged if ok is not None]
            if judged:
                failed = [n for n, ok in judged if not ok]
                print(f"{est}, {c}: {len(judged)} judged, converged within 15 frames "
                      f"{1 - len(failed) / len(judged):.3f}; failed: {', '.join(failed) or '-'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
