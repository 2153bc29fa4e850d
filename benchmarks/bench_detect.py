"""Shaft-edge detectors on simulated recordings they were not trained on.

    python benchmarks/bench_detect.py [--frames 200] [--sold2 CKPT]   # prints the figures
    run(results)                                                      # fills results["detect"]

For each scene (structured, tissue) one plain (not randomised) recording of
FRAMES frames at 540x960 is simulated with seed SEEDS[scene] (the learned
detector's training recordings use seeds >= 100000 and are randomised 3 in 4);
each frame is undistorted and given to every detector (canny, learned, and
sold2 when a checkpoint is given) twice:

- free: no prediction (the association's pair search);
- gated: with a prediction = the true limb lines, perturbed by N(0, 5 px) in
  offset and N(0, 0.03 rad) in angle (what the tracker passes).

Truth: the limb lines shaft_lines(base_features(robot, q~).transformed(E_t), K)
(undistorted px). Figures per detector, scene and mode: ``both`` = fraction of
frames with both shaft edges found, each within 10 px and 0.05 rad of a true
limb line (wrong lines do not count); ``rho_px`` / ``theta_rad`` = median
|d_rho| / |d_theta| of the detected edges against their nearest true line;
``ms`` = median detection time per frame, one thread (torch, OpenCV).
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # runnable from a checkout

FRAMES = 200
SEEDS = {"structured": 7, "tissue": 8}
TOL_RHO, TOL_THETA = 10.0, 0.05


def _errors(lines, rho, th):
    from graphtrack.geometry.lines import line_difference

    out = []
    for r, t in np.asarray(lines).reshape(-1, 2):
        dr, dt = line_difference(r, t, rho, th)
        j = int(np.argmin(np.abs(dr) / TOL_RHO + np.abs(dt) / TOL_THETA))
        out.append((abs(float(dr[j])), abs(float(dt[j]))))
    return out


def run(results: dict, frames: int = FRAMES, sold2: str | None = None, log=print) -> dict:
    import cv2
    import torch

    from graphtrack.detect import make_detector
    from graphtrack.robot.features import base_features, shaft_lines
    from graphtrack.sim.simulate import Simulation

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    dets = {"canny": make_detector("canny"), "learned": make_detector("learned")}
    if sold2:
        dets["sold2"] = make_detector("sold2", weights=sold2)
    out: dict = {}
    for scene, seed in SEEDS.items():
        sim = Simulation(scene, frames, seed=seed, size=(540, 960))
        cam = sim.camera
        rng = np.random.default_rng(seed)
        acc = {(n, m): {"both": 0, "err": [], "ms": [], "n": 0} for n in dets for m in ("free", "gated")}
        for i in range(frames):
            raw, _ = sim.render(i)
            und = cam.undistort(raw)
            rho, th, ok = shaft_lines(base_features(sim.robot, sim.q_read[i]).transformed(sim.E_t[i]), cam.K)
            if not ok:
                continue
            pred = np.stack([rho + rng.normal(0, 5.0, 2), th + rng.normal(0, 0.03, 2)], 1)
            for name, det in dets.items():
                for mode, p in (("free", None), ("gated", pred)):
                    d = det.detect(und, p)
                    a = acc[(name, mode)]
                    a["n"] += 1
                    a["ms"].append(d.ms)
                    e = _errors(d.shaft_lines, rho, th)
                    a["err"] += e
                    good = [x for x in e if x[0] <= TOL_RHO and x[1] <= TOL_THETA]
                    a["both"] += int(len(good) == 2)
        for (name, mode), a in acc.items():
            e = np.array(a["err"]).reshape(-1, 2)
            out.setdefault(name, {}).setdefault(scene, {})[mode] = {
                "both": round(a["both"] / max(a["n"], 1), 3),
                "rho_px": round(float(np.median(e[:, 0])), 2) if len(e) else None,
                "theta_rad": round(float(np.median(e[:, 1])), 4) if len(e) else None,
                "ms": round(float(np.median(a["ms"])), 1) if a["ms"] else None,
                "frames": a["n"]}
            log(f"{name:8s} {scene:10s} {mode:5s} " + json.dumps(out[name][scene][mode]))
    results["detect"] = out
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=FRAMES)
    ap.add_argument("--sold2", metavar="CKPT", help="SOLD2 checkpoint to include the sold2 detector")
    a = ap.parse_args(argv)
    res: dict = {}
    run(res, a.frames, a.sold2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
