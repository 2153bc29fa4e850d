"""Stereo speed (issue #19): the learned + stereo smoother's frame rate and the stereo
particle-filter step. Accuracy is bench_stereo.py; this section is the one that depends
on the machine, so it is kept apart: the accuracy can be re-measured anywhere without
replacing the reference machine's timings.

    python benchmarks/run_all.py stereo_speed      # pinned to one core

Track: the stereo benchmark's recordings (bench_stereo.RECORDINGS, held out) tracked
by the smoother with the learned detector and line-intensities, both images and
``--mono``: frames/s in the steady state (1000 / mean per-frame ms of frames 1.., as
bench_track.py reads ``fps_steady``), median over the recordings. PF: one predict +
update of 1000 particles with both images' observations (~500 shaft pixels, 4 markers
and the shaft end each), as bench_pf.py times the mono step (median of 200 after 20
warm-up steps).
"""
from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[0]))  # runnable from a checkout
sys.path.insert(0, str(HERE))

from bench_stereo import RECORDINGS, _track, recording  # noqa: E402


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


def _fps(out: dict, work: Path) -> None:
    for stereo, name in ((True, "stereo"), (False, "mono")):
        fps = [_track(recording(scene, seed), work / f"{seed}-{name}", "smoother", stereo)["fps_steady"]
               for scene, seed in RECORDINGS]
        out[f"fps_540_learned_{name}_smoother"] = float(statistics.median(fps))


def run(results: dict) -> dict:
    from graphtrack.threads import limit_threads

    limit_threads(1)
    out = results.setdefault("stereo_speed", {})
    out["recordings"] = [f"{s}:{seed}" for s, seed in RECORDINGS]
    _pf(out)
    with tempfile.TemporaryDirectory() as tmp:
        _fps(out, Path(tmp))
    return out


if __name__ == "__main__":
    print(json.dumps(run({}), indent=1, default=str))
