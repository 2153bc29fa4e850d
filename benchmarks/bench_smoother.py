"""Timings of the factor-graph backend on synthetic data (one core: run under taskset -c 0).

    python benchmarks/bench_smoother.py

Prints and fills ``results``: median / p90 online update (ms per frame) at
lags 0.5 ... 5 s with ~500 shaft pixels + markers, the 1 s-lag accuracy and
the time-averaged NEES of that one sequence (informative only: its frames are
correlated), the Monte-Carlo NEES over ``nees_runs`` independent runs (the
consistency target, :mod:`graphtrack.eval.consistency`), the update time
with and without the edge-bias state (interleaved runs), the start-up
success rate from hand-eye errors drawn from the prior (also without the
edge-bias state), and the batch refinement time of ``n_batch`` frames.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from functools import partial

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphtrack.sim.synthetic import make_scene, sequence  # noqa: E402
from graphtrack.detect.base import Observation  # noqa: E402
from graphtrack.io.frame import Frame  # noqa: E402
from graphtrack.estimate.batch import BatchEstimator  # noqa: E402
from graphtrack.io.context import TrackingContext  # noqa: E402
from graphtrack.estimate.graph import left_error  # noqa: E402
from graphtrack.estimate.options import LAG_S  # noqa: E402
from graphtrack.estimate.smoother import FixedLagSmootherEstimator  # noqa: E402


def _obs(f):
    return Observation("line-intensities", pixels=f.pixels, markers=f.markers)


def nees_monte_carlo(results: dict, runs: int = 200) -> None:
    """Monte-Carlo NEES at 1 s lag: one value per independent run, frame ~ U[60, 200), with the
    pixel model that matches the synthetic generator (independent, unbiased pixels:
    pixel_effective_count=0, edge_bias=False)."""
    from graphtrack.eval.consistency import monte_carlo_nees

    t0 = time.perf_counter()
    # synthetic pixels are independent and unbiased: the matched model counts every pixel
    # (no tempering) and has no edge-bias state
    res = monte_carlo_nees(lambda ctx: FixedLagSmootherEstimator(ctx, lag=LAG_S, pixel_effective_count=0,
                                                                 edge_bias=False),
                           partial(sequence, scene=make_scene()), runs=runs, first=60, last=200,
                           pixel_noise=1.5, marker_noise=2.0, progress=True)
    results["nees_mc_runs"] = runs
    results["nees_mc_mean"] = res.mean
    results["nees_mc_band_lo"], results["nees_mc_band_hi"] = res.band
    results["nees_mc_inside"] = res.inside
    print(f"Monte-Carlo NEES over {runs} runs: {res.mean:.2f} (95% band {res.band[0]:.2f}-{res.band[1]:.2f}) "
          f"[{time.perf_counter() - t0:.0f} s]", flush=True)


def start_up(results: dict, runs: int = 100, frames: int = 41) -> None:
    """Runs within 3 mm of the truth at frame ``frames - 1`` from hand-eye errors ~ the prior
    (5 mm / 2 deg per axis), smoother and particle filter, same sequences."""
    from graphtrack.estimate.particle_filter import ParticleFilter

    scene = make_scene()
    pick = np.random.default_rng(0)
    ok = {"smoother": 0, "smoother_no_edge_bias": 0, "pf": 0}
    for r in range(runs):
        err = pick.standard_normal(6) * np.repeat([5e-3, 0.035], 3)
        robot, cam, E0, seq = sequence(frames, seed=1000 + r, scene=scene, handeye_error=err,
                                       walk_sigma=(2.5e-5, 1e-4), pixel_noise=1.5, marker_noise=2.0,
                                       pixels_per_edge=60)
        ctx = TrackingContext(robot, cam, E0)
        for name, est in (("smoother", FixedLagSmootherEstimator(ctx)),
                          ("smoother_no_edge_bias", FixedLagSmootherEstimator(ctx, edge_bias=False)),
                          ("pf", ParticleFilter(ctx, seed=r))):
            for f in seq:
                e = est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]), _obs(f))
            ok[name] += bool(np.linalg.norm(left_error(seq[-1].E_true, e.E)[:3]) < 3e-3)
    for name, n in ok.items():
        results[f"start_up_within_3mm_{name}"] = n / runs
    print(f"start-up from prior-drawn hand-eye errors, within 3 mm at frame {frames - 1}: "
          f"smoother {ok['smoother']}/{runs} ({ok['smoother_no_edge_bias']}/{runs} without the edge-bias state), "
          f"particle filter {ok['pf']}/{runs}", flush=True)


def edge_bias_cost(results: dict, ctx, frames, rounds: int = 3) -> None:
    """Median update at 1 s lag with and without the edge-bias state, runs interleaved
    (the shared machine's speed drifts by tens of per cent between runs)."""
    meds = {True: [], False: []}
    for _ in range(rounds):
        for on in (True, False):
            est = FixedLagSmootherEstimator(ctx, lag=LAG_S, edge_bias=on)
            for f in frames:
                est.step(Frame(f.index, f.stamp, None, f.q[:6], f.q[6]), _obs(f))
            meds[on].append(float(np.median(est.timings_ms[30:])))
    results["online_lag1.0_edge_bias_ab_ms"] = float(np.median(meds[True]))
    results["online_lag1.0_no_edge_bias_ab_ms"] = float(np.median(meds[False]))
    print(f"lag  1.0 s, interleaved: update median {results['online_lag1.0_edge_bias_ab_ms']:.2f} ms with the "
          f"edge-bias state, {results['online_lag1.0_no_edge_bias_ab_ms']:.2f} ms without", flush=True)


def run(results: dict, n_online: int = 300, n_batch: int = 1800, lags=(0.5, 1.0, 2.0, 5.0),
        nees_runs: int = 200, start_up_runs: int = 100) -> dict:
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
        results[f"online_lag{lag}_sequence_mean_nees"] = float(np.mean(nees[60:]))
        print(f"lag {lag:4.1f} s: update median {np.median(t):6.2f} ms, p90 {np.percentile(t, 90):6.2f} ms, "
              f"rms {results[f'online_lag{lag}_rms_mm']:.3f} mm / {results[f'online_lag{lag}_rms_deg']:.3f} deg, "
              f"NEES of this sequence {results[f'online_lag{lag}_sequence_mean_nees']:.2f}", flush=True)
    edge_bias_cost(results, ctx, frames)
    if nees_runs:
        nees_monte_carlo(results, nees_runs)
    if start_up_runs:
        start_up(results, start_up_runs)
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
