"""Stereo against mono (issue #19): accuracy, speed of the stereo pipeline, the stereo PF step.

    python benchmarks/run_all.py stereo      # pinned to one core; writes results.json / RESULTS.md

Accuracy. Simulated stereo recordings from held-out seeds (SEED0.., see there; 150
frames, 540x960, alternating structured and tissue) are tracked with the learned
detector and line-intensities by the smoother and the batch, once with both images
and once with ``--mono``. Per frame, against truth.csv: the 3-D tip error (mm, the
exact tip against E_t . tip(q~)) and the 2-D tip error in the left raw image (px).
Reported: each view's mean over all frames, the ratio stereo / mono, and the paired
difference stereo - mono with its moving-block bootstrap interval
(:func:`graphtrack.eval.metrics.paired_difference`, as bench_accuracy.py), per estimator.

Speed. The stereo smoother runs above are timed by ``track`` itself: frames/s in the
steady state (1000 / mean per-frame ms of frames 1.., as bench_track.py reads
``fps_steady``), median over the recordings. PF: one predict + update of 1000
particles with both images' observations (~500 shaft pixels, 4 markers and the shaft end each), as
bench_pf.py times the mono step (median of 200 after 20 warm-up steps).
"""
from __future__ import annotations

import csv
import json
import os
import statistics
import sys
import time
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
    m["_tip_mm"] = np.array([float(r["tip_mm"]) for r in rows])
    m["_tip2d_px"] = np.array([float(r["tip2d_px"]) for r in rows])
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
    fps = [runs[r, s_, "smoother", True]["fps_steady"] for r, s_ in RECORDINGS]
    out["fps_540_learned_stereo_smoother"] = float(statistics.median(fps))
    out["fps_540_learned_mono_smoother"] = float(statistics.median(
        runs[r, s_, "smoother", False]["fps_steady"] for r, s_ in RECORDINGS))
    out["left_only_frames"] = int(sum(runs[k].get("frames_left_only", 0) for k in runs))
    out.setdefault("tables", {})["stereo vs mono, learned + line-intensities, against truth.csv"] = "\n".join(lines)


def _pf(out: dict) -> None:
    from graphtrack.detect.base import Observation
    from graphtrack.estimate.options import PARTICLES
    from graphtrack.estimate.particle_filter import ParticleFilter
    from graphtrack.geometry.camera import Camera
    from graphtrack.io.context import TrackingContext
    from graphtrack.robot.features import base_features
    from graphtrack.sim.stereo import rig, to_right
    from graphtrack.sim.synthetic import HANDEYE_ERROR, Scene, make_scene, observe, sequence

    scene = make_scene()
    cam = scene.camera
    C = to_right(*rig())
    right = Camera(cam.K.copy(), np.zeros(5), cam.height, cam.width)
    ctx = TrackingContext(scene.robot, cam, scene.E0, right, C)
    E_true = scene.true_E(HANDEYE_ERROR)
    seq = sequence(64, seed=0, scene=scene, pixels_per_edge=250, outliers=0.05, marker_model="point",
                   shaft_end_noise=1.0)
    rng = np.random.default_rng(0)
    frames = []
    for f in seq.frames:
        # all four markers in each image, visible or not, as bench_pf.py
        m = base_features(scene.robot, f.q).transformed(E_true).points
        mk = cam.project_undistorted(m) + rng.standard_normal((4, 2))
        left = Observation("line-intensities", pixels=f.pixels, markers=mk, edge_ids=np.arange(2),
                           shaft_end=f.shaft_end)
        o = observe(Scene(scene.robot, right, scene.E0), f.q, C @ E_true, rng, pixels_per_edge=250,
                    outliers=0.05, marker_model="point", shaft_end_noise=1.0)
        mr = right.project_undistorted(m @ C[:3, :3].T + C[:3, 3]) + rng.standard_normal((4, 2))
        frames.append((f.frame(), left, Observation("line-intensities", pixels=o.pixels, markers=mr,
                                                    edge_ids=np.arange(2), shaft_end=o.shaft_end)))
    for stereo in (True, False):
        pf = ParticleFilter(ctx, particles=PARTICLES, seed=0)
        ts = []
        for k in range(220):
            fr, ol, orr = frames[k % len(frames)]
            t0 = time.perf_counter()
            pf.step(fr, ol, orr if stereo else None)
            if k >= 20:
                ts.append(time.perf_counter() - t0)
        out["pf_step_ms_1000_" + ("stereo" if stereo else "mono")] = 1e3 * statistics.median(ts)


def run(results: dict) -> dict:
    import tempfile

    from graphtrack.threads import limit_threads

    limit_threads(1)
    out = results.setdefault("stereo", {})
    out["recordings"] = [f"{s}:{seed}" for s, seed in RECORDINGS]
    _pf(out)
    with tempfile.TemporaryDirectory() as tmp:
        _accuracy(out, Path(tmp))
    return out


if __name__ == "__main__":
    res = run({})
    print(json.dumps({k: v for k, v in res.items() if k != "tables"}, indent=1, default=str))
