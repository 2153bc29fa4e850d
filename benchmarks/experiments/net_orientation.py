"""The learned net's line heatmap on the true shaft edges against the edges' image angle.

    python3 benchmarks/experiments/net_orientation.py [--recordings 6] [--turn] [--weights PT]

Each frame (frame 20 of plain simulated recordings, seeds 810000 + k, both scenes; the
net was not trained on them) is resized to the net's 1/4 scale, undistorted, padded by
replicating its border, and turned about its centre in 5-degree steps; the net reads
each turned image. Per turn, the figure is the smaller over the two edges of the
median heatmap value on the true edge (the 3x3 maximum around 30 points along its
middle 70 %), at the edge's image angle after the turn (deg from the horizontal, y
down). ``--turn``: the detector's own input handling instead of the net alone
(:mod:`graphtrack.detect.turn`, the input turned by 45 deg in the blind zone).
Printed: per 5-degree bin of |angle|, the median and the minimum over the frames.
Measurements: docs/decisions/net-orientation.md.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))   # runnable from a checkout


def _edge_values(L: np.ndarray, seg: np.ndarray, A: np.ndarray) -> float:
    t = np.linspace(0.15, 0.85, 30)
    p = seg[:2] + t[:, None] * (seg[2:] - seg[:2])
    q = np.rint(p @ A[:, :2].T + A[:, 2]).astype(int)
    ok = (q[:, 0] >= 1) & (q[:, 0] < L.shape[1] - 1) & (q[:, 1] >= 1) & (q[:, 1] < L.shape[0] - 1)
    v = [L[y - 1:y + 2, x - 1:x + 2].max() for x, y in q[ok]]
    return float(np.median(v)) if v else float("nan")


def frame_sweep(det, sim, k: int, pad: int, use_turn: bool) -> list[tuple[float, float]]:
    """(edge angle deg, min over the edges of the median heatmap on it) per 5-degree turn."""
    from graphtrack.detect.turn import turn_for, turned, turned_back
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.training.labels import shaft_edge_segments

    raw, _ = sim.render(k)
    cam = sim.camera
    small = cam.undistort_resized(cv2.resize(raw, (raw.shape[1] // 4, raw.shape[0] // 4),
                                             interpolation=cv2.INTER_AREA))
    segs = shaft_edge_segments(sim.robot, sim.q_true[k], sim.E_he, cam.K, cam.height, cam.width)
    segs = (np.asarray(segs, float).reshape(-1, 4) + 0.5) / 4 - 0.5 + pad
    big = cv2.copyMakeBorder(small, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    rho, th, _ = shaft_lines(base_features(sim.robot, sim.q_true[k]).transformed(sim.E_he), cam.K)
    out = []
    for deg in range(0, 180, 5):
        A = cv2.getRotationMatrix2D(((big.shape[1] - 1) / 2, (big.shape[0] - 1) / 2), deg, 1.0)
        x = cv2.warpAffine(big, A, (big.shape[1], big.shape[0]), borderMode=cv2.BORDER_REPLICATE)
        if use_turn:   # the turned lines, as a tracker would predict them
            d = A[:, :2] @ np.stack([np.cos(th + math.pi / 2), np.sin(th + math.pi / 2)])
            lines = np.stack([np.zeros(2), np.arctan2(d[1], d[0]) - math.pi / 2], 1)
            t = turn_for(lines)
            if t:
                canvas, At = turned(x, t)
                L = turned_back(det._net(canvas)[0], At, x.shape[:2])
            else:
                L = det._net(x)[0]
        else:
            L = det._net(x)[0]
        d0 = A[:, :2] @ (segs[0, 2:] - segs[0, :2])
        a = (math.degrees(math.atan2(d0[1], d0[0])) + 90.0) % 180.0 - 90.0
        out.append((a, min(_edge_values(L, s, A) for s in segs[:2])))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recordings", type=int, default=6, help="recordings per scene")
    p.add_argument("--turn", action="store_true", help="the detector's turned input in the blind zone")
    p.add_argument("--weights", metavar="PT", help="learned-detector weights (default: the shipped ones)")
    args = p.parse_args(argv)
    from graphtrack.detect.learned import LearnedDetector
    from graphtrack.sim.simulate import Simulation
    from graphtrack.threads import limit_threads

    limit_threads(1)
    det = LearnedDetector(args.weights)
    rows = []
    for i in range(args.recordings):
        for scene in ("structured", "tissue"):
            sim = Simulation(scene, 30, seed=810_000 + i, size=(540, 960))
            rows += frame_sweep(det, sim, 20, 40, args.turn)
    a = np.array(rows)
    print("| edge angle (deg from horizontal) | median heatmap on the edges | minimum |")
    print("|---|---|---|")
    for lo in range(0, 90, 5):
        sel = (np.abs(a[:, 0]) >= lo) & (np.abs(a[:, 0]) < lo + 5)
        if sel.any():
            print(f"| {lo}-{lo + 5} | {np.nanmedian(a[sel, 1]):.2f} | {np.nanmin(a[sel, 1]):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
