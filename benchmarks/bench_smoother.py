"""Timings of the factor-graph backend on synthetic data (one core: run under taskset -c 0).

    python benchmarks/bench_smoother.py

Prints and fills ``results``: median / p90 online update (ms per frame) at
lags 0.5 ... 5 s with ~500 shaft pixels + markers, the 1 s-lag accuracy and
mean NEES, and the batch refinement time of ``n_batch`` frames.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from factors.synthetic import make_scene, sequence  # noqa: E402
from graphtrack.detect.base import Observation  # noqa: E402
from graphtrack.estimate.base import Frame  # noqa: E402
from graphtrack.estimate.batch import BatchEstimator  # noqa: E402
from graphtrack.estimate.context import TrackingContext  # noqa: E402
from graphtrack.estimate.graph import left_error  # noqa: E402
from graphtrack.estimate.smoother import FixedLagSmootherEstimator  # noqa: E402


def _obs(f):
    return Observation("line-intensities", pixels=f.pixels, markers=f.markers)


def run(results: dict, n_online: int = 300, n_batch: int = 1800, lags=(0.5, 1.0, 2.0, 5.0)) -> dict:
    scene = make_scene()
    robot, cam, E0, frames = sequence(max(n_online, 1), seed=1, scene=scene, walk_sigma=(2.5e-5, 1e-4),
                                      pixel_noise=1.5, marker_noise=2.0)
    ctx = TrackingContext(robot, cam, E0)
    for lag in lags:
        est = FixedLagSmootherEstimator(ctx, lag=lag)
        errs, nees = [], []
        for f in frames:
            e = est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]), _obs(f))
            x = left_error(f.E_true, e.E)
            errs.append(x)
            nees.append(x @ np.linalg.solve(e.cov, x))
        t = np.array(est.timings_ms[30:])
        errs = np.array(errs[60:])
        results[f"online_lag{lag}_median_ms"] = float(np.median(t))
        results[f"online_lag{lag}_p90_ms"] = float(np.percentile(t, 90))
        results[f"online_lag{lag}_rms_mm"] = float(np.sqrt(np.mean(errs[:, :3] ** 2)) * 1e3)
        results[f"online_lag{lag}_rms_deg"] = float(np.degrees(np.sqrt(np.mean(errs[:, 3:] ** 2))))
        results[f"online_lag{lag}_mean_nees"] = float(np.mean(nees[60:]))
        print(f"lag {lag:4.1f} s: update median {np.median(t):6.2f} ms, p90 {np.percentile(t, 90):6.2f} ms, "
              f"rms {results[f'online_lag{lag}_rms_mm']:.3f} mm / {results[f'online_lag{lag}_rms_deg']:.3f} deg, "
              f"NEES {results[f'online_lag{lag}_mean_nees']:.2f}", flush=True)
    if n_batch:
        _, _, _, bframes = sequence(n_batch, seed=2, scene=scene, walk_sigma=(2.5e-5, 1e-4),
                                    pixel_noise=1.5, marker_noise=2.0)
        est = BatchEstimator(ctx)
        for f in bframes:
            est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]), _obs(f))
        t0 = time.perf_counter()
        out = est.finish()
        dt = time.perf_counter() - t0
        errs = np.array([left_error(f.E_true, e.E) for f, e in zip(bframes, out)])
        results["batch_frames"] = n_batch
        results["batch_s"] = dt
        results.update({f"batch_{k}": v for k, v in est.stats.items()})
        results["batch_rms_mm"] = float(np.sqrt(np.mean(errs[:, :3] ** 2)) * 1e3)
        results["batch_rms_deg"] = float(np.degrees(np.sqrt(np.mean(errs[:, 3:] ** 2))))
        print(f"batch {n_batch} frames: {dt:.1f} s ({est.stats}), rms {results['batch_rms_mm']:.3f} mm / "
              f"{results['batch_rms_deg']:.3f} deg", flush=True)
    return results


if __name__ == "__main__":
    run({})
