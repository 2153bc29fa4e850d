"""Particle filter speed: one predict + update (+ estimate, + resampling when due).

    python benchmarks/bench_pf.py            # prints the figures
    run(results)                             # fills results["pf"] for a benchmark runner

One core: OMP/OpenBLAS/MKL threads and torch's intra-op threads are set to 1.
The scene is graphtrack.sim.synthetic (PSM + Large Needle Driver, a
1280x1024 f = 1100 px camera): every step reads a different joint vector of
a smooth trajectory, ~500 shaft pixels (line-intensities, 2 edges, 5 %
outliers) and 4 detected markers. Figures are medians over REPEATS steps
after WARMUP steps. ``loop_ratio`` compares with a straightforward
per-particle Python loop (written here only: per particle E(x_n), features,
limb lines, numpy residuals over the pixels, Hungarian marker association)
measured in the same run on the same inputs.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # runnable from a checkout

WARMUP = 20
REPEATS = 200
LOOP_REPEATS = 5
COUNTS = (100, 300, 1000, 3000, 10000)


def _inputs(n_frames: int = 64):
    from graphtrack.detect.base import Observation
    from graphtrack.robot.features import base_features
    from graphtrack.sim.synthetic import HANDEYE_ERROR, make_scene, sequence

    scene = make_scene()
    seq = sequence(n_frames, seed=0, scene=scene, pixels_per_edge=250, outliers=0.05, marker_model="point",
                   shaft_end_noise=1.0)
    E_true = scene.true_E(HANDEYE_ERROR)
    rng = np.random.default_rng(0)
    frames = []
    for f in seq.frames:
        # all four markers, visible or not, so that every step scores 4
        m = base_features(scene.robot, f.q).transformed(E_true).points
        mk = scene.camera.project_undistorted(m) + rng.standard_normal((4, 2))
        obs = Observation("line-intensities", pixels=f.pixels, markers=mk, edge_ids=np.arange(2),
                          shaft_end=f.shaft_end)
        frames.append((f.frame(), obs))
    return scene, frames


def _time_steps(pf, frames, repeats: int, warmup: int) -> list[float]:
    ts = []
    for k in range(warmup + repeats):
        fr, obs = frames[k % len(frames)]
        t0 = time.perf_counter()
        pf.step(fr, obs)
        if k >= warmup:
            ts.append(time.perf_counter() - t0)
    return ts


class LoopFilter:
    """The same filter written particle by particle (benchmark reference only)."""

    def __init__(self, pf):
        self.pf = pf

    def step(self, frame, obs):
        from scipy.optimize import linear_sum_assignment

        from graphtrack.estimate.observation_models import marker_cost
        from graphtrack.estimate.resampling import (effective_sample_size, normalize_log_weights,
                                                    systematic_resample)
        from graphtrack.geometry.lines import pixel_residual
        from graphtrack.geometry.se3 import average_rotations, bw_to_matrix
        from graphtrack.robot.features import base_features, shaft_lines

        pf = self.pf
        pf.predict()
        f = base_features(pf.robot, frame.q)
        pixels = np.concatenate(obs.pixels)
        floor = (pf.shaft_options["pixel_outlier_sigmas"] * pf.shaft_options["pixel_sigma"]) ** 2
        sig2 = pf.shaft_options["pixel_sigma"] ** 2
        ll = np.zeros(pf.N)
        Rs = np.zeros((pf.N, 3, 3))
        for n in range(pf.N):
            E = bw_to_matrix(pf.x[n]) @ pf.E0
            Rs[n] = E[:3, :3] @ pf.E0[:3, :3].T
            cam = f.transformed(E)
            rho, theta, valid = shaft_lines(cam, pf.K)
            if not valid:
                ll[n] = -1e6
                continue
            r = pixel_residual(pixels[None], rho[:, None], theta[:, None])  # (2, P)
            ll[n] = -np.minimum(np.min(r * r, axis=0), floor).sum() / (2 * sig2)
            px = pf.ctx.camera.project_undistorted(cam.points)
            d = np.linalg.norm(px[:, None] - obs.markers[None], axis=-1)
            c = marker_cost(np.minimum(d, pf.marker_gate), gamma=pf.marker_gamma, **pf.marker_options)
            i, j = linear_sum_assignment(c)
            ll[n] += -c[i, j].sum()
        pf.logw = normalize_log_weights(pf.logw + ll)
        w = np.exp(pf.logw)
        pf.x_mean = w @ pf.x
        pf.R_mean = average_rotations(Rs, w)
        if effective_sample_size(w) < pf.resample_threshold * pf.N:
            idx = systematic_resample(w, pf.rng)
            pf.x = pf.x[idx]
            pf.logw = np.full(pf.N, -np.log(pf.N))


def run(results: dict) -> dict:
    from graphtrack.estimate.options import PARTICLES
    from graphtrack.estimate.particle_filter import ParticleFilter
    from graphtrack.threads import limit_threads

    limit_threads(1)

    out = results.setdefault("pf", {})
    scene, frames = _inputs()
    out["pixels_per_frame"] = float(np.mean([sum(len(p) for p in o.pixels) for _, o in frames]))
    rows = []
    for n in COUNTS:
        pf = ParticleFilter(scene.ctx, particles=n, seed=0)
        reps = REPEATS if n <= 3000 else REPEATS // 4
        ts = _time_steps(pf, frames, reps, WARMUP)
        ms = 1e3 * statistics.median(ts)
        out[f"step_ms_{n}"] = ms
        rows.append(f"| {n} | {ms:.3f} | {1e3 * np.percentile(ts, 90):.3f} | {1e6 * statistics.median(ts) / n:.2f} |")
    pf = ParticleFilter(scene.ctx, particles=PARTICLES, seed=0)   # the default count
    loop = LoopFilter(ParticleFilter(scene.ctx, particles=PARTICLES, seed=0))
    vec_ms = 1e3 * statistics.median(_time_steps(pf, frames, REPEATS, WARMUP))
    loop_ms = 1e3 * statistics.median(_time_steps(loop, frames, LOOP_REPEATS, 1))
    out[f"step_ms_{PARTICLES}_again"] = vec_ms
    out[f"loop_step_ms_{PARTICLES}"] = loop_ms
    out["loop_ratio"] = loop_ms / vec_ms
    out.setdefault("tables", {})["step time vs particle count (line-intensities, ~500 px, 4 markers, the shaft end)"] = "\n".join(
        ["| particles | median ms | p90 ms | us / particle |", "|---|---|---|---|"] + rows)
    out.setdefault("notes", []).append(
        f"Per-particle Python loop (same model, same inputs): {loop_ms:.1f} ms per step, "
        f"{loop_ms / vec_ms:.0f}x the vectorised filter ({vec_ms:.2f} ms).")
    return results


if __name__ == "__main__":
    res = run({})["pf"]
    for k, v in res.items():
        if k not in ("tables", "notes"):
            print(f"{k}: {v:.3f}" if isinstance(v, float) else f"{k}: {v}")
    for title, md in res["tables"].items():
        print(f"\n{title}\n{md}")
    for note in res["notes"]:
        print("\n" + note)
