"""Stereo against mono (issue #19): accuracy. Its speed is bench_stereo_speed.py.

    python benchmarks/run_all.py stereo      # pinned to one core; writes results.json / RESULTS.md

Simulated stereo recordings from held-out seeds (SEED0.., see there; 150 frames,
540x960, alternating structured and tissue) are tracked with the learned detector and
line-intensities by the smoother and the batch, once with both images and once with
``--mono``. Per frame, against truth.csv: the 3-D tip error (mm: the tip from the joint
readings placed by E_t, E_t . tip(q~), against the exact tip, truth.csv's tip_x, tip_y,
tip_z) and the 2-D tip error in the left raw image (px, against the exact tip_u, tip_v).
Reported: each view's mean over all frames, the ratio stereo / mono, and the paired
difference stereo - mono with its moving-block bootstrap interval
(:func:`graphtrack.eval.metrics.paired_difference`, as bench_accuracy.py), per estimator;
and the 3-D error's mean components along the true tip's viewing ray (|depth|) and
across it (lateral), mm, per view (truth_errors.csv's tip_depth_mm, tip_lateral_mm).
These figures do not depend on the machine (the speed section's do), so this section
may be re-run on any machine.
"""
from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[0]))  # runnable from a checkout
DATA = Path(os.environ.get("GRAPHTRACK_BENCH_DATA", HERE / ".data"))
SEED0 = 940_000   # held out: nothing is tuned or trained on 940000-940999 (700000-700999 are tuning seeds)
RECORDINGS = [(("structured", "tissue")[i % 2], SEED0 + i) for i in range(8)]
FRAMES = 150
ESTIMATORS = ("smoother", "batch")


def recording(scene: str, seed: int) -> Path:
    from graphtrack.sim.simulate import simulated_once

    return simulated_once(DATA / f"stereo-{scene}-540x960-{FRAMES}-{seed}", scene=scene, frames=FRAMES,
                          seed=seed, size=(540, 960), stereo=True, progress=False)


def _track(path: Path, out: Path, estimator: str, stereo: bool) -> dict:
    from graphtrack.detect.options import DetectionOptions
    from graphtrack.track import TrackOptions, track

    opts = TrackOptions(estimator=estimator, observation="line-intensities",
                        detection=DetectionOptions(detector="learned"), stereo=stereo)
    m = track(path, out, opts, progress=False, quiet=True, overwrite=True)
    with (out / "truth_errors.csv").open() as f:
        rows = list(csv.DictReader(f))
    for key in ("tip_mm", "tip2d_px", "tip_depth_mm", "tip_lateral_mm"):
        m["_" + key] = np.array([float(r[key]) for r in rows])
    return m


def _accuracy(out: dict, work: Path) -> None:
    from graphtrack.eval.metrics import paired_difference

    runs = {}
    for scene, seed in RECORDINGS:
        path = recording(scene, seed)
        for est in ESTIMATORS:
            for stereo in (True, False):
                runs[scene, seed, est, stereo] = _track(path, work / f"{seed}-{est}-{stereo}", est, stereo)
    lines = ["| estimator | figure | mono | stereo | stereo / mono | stereo - mono [95 % CI] |", "|---|---|---|---|---|---|"]
    for est in ESTIMATORS:
        for key, unit in (("_tip_mm", "mm"), ("_tip2d_px", "px")):
            s = np.concatenate([runs[r, s_, est, True][key] for r, s_ in RECORDINGS])
            m = np.concatenate([runs[r, s_, est, False][key] for r, s_ in RECORDINGS])
            ratio = float(np.nanmean(s) / np.nanmean(m))
            name = "tip3d" if key == "_tip_mm" else "tip2d_left"
            out[f"{est}_{name}_mono"] = float(np.nanmean(m))
            out[f"{est}_{name}_stereo"] = float(np.nanmean(s))
            out[f"{est}_{name}_ratio"] = ratio
            # paired per recording (blocks never span two recordings), pooled by frames
            diffs = [paired_difference(runs[r, s_, est, True][key], runs[r, s_, est, False][key])
                     for r, s_ in RECORDINGS]
            pooled = paired_difference(s, m)
            out[f"{est}_{name}_diff"] = pooled
            lines.append(f"| {est} | {name} ({unit}) | {np.nanmean(m):.3f} | {np.nanmean(s):.3f} | {ratio:.2f} | "
                         f"{pooled['mean']:+.3f} [{pooled['low']:+.3f}, {pooled['high']:+.3f}] |")
            out[f"{est}_{name}_diff_per_recording"] = [d["mean"] for d in diffs]
        for view in ("mono", "stereo"):     # where the 3-D error lies: along the viewing ray or across it
            rs = [runs[r, s_, est, view == "stereo"] for r, s_ in RECORDINGS]
            out[f"{est}_tip3d_depth_{view}"] = float(np.nanmean(np.abs(np.concatenate([x["_tip_depth_mm"] for x in rs]))))
            out[f"{est}_tip3d_lateral_{view}"] = float(np.nanmean(np.concatenate([x["_tip_lateral_mm"] for x in rs])))
        lines.append(f"| {est} | tip3d depth / lateral (mm) | {out[f'{est}_tip3d_depth_mono']:.3f} / "
                     f"{out[f'{est}_tip3d_lateral_mono']:.3f} | {out[f'{est}_tip3d_depth_stereo']:.3f} / "
                     f"{out[f'{est}_tip3d_lateral_stereo']:.3f} | | |")
    out["left_only_frames"] = int(sum(runs[k].get("frames_left_only", 0) for k in runs))
    out.setdefault("tables", {})["stereo vs mono, learned + line-intensities, against truth.csv"] = "\n".join(lines)


def run(results: dict) -> dict:
    import tempfile

    from graphtrack.threads import limit_threads

    limit_threads(1)
    out = results.setdefault("stereo", {})
    out["recordings"] = [f"{s}:{seed}" for s, seed in RECORDINGS]
    with tempfile.TemporaryDirectory() as tmp:
        _accuracy(out, Path(tmp))
    return out


if __name__ == "__main__":
    res = run({})
    print(json.dumps({k: v for k, v in res.items() if k != "tables"}, indent=1, default=str))
