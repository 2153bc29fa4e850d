"""Covariance consistency of an estimator by Monte-Carlo NEES on synthetic sequences.

NEES_t = xi_t^T P_t^-1 xi_t, with xi_t the left (b, w) error of E_t
(E_true = Exp(xi) . E_est) and P_t the estimator's reported covariance.
If the estimator is consistent, each NEES_t ~ chi2(6) and the mean of R
INDEPENDENT values lies in the two-sided 95 % band chi2.ppf([0.025, 0.975], 6R) / R
(R = 200: [5.53, 6.49]).

Each run contributes ONE value, at a frame drawn uniformly from [first, last),
with its own seed (pixel and marker noise, random walk of the true E) and,
optionally, its own hand-eye error drawn from a prior: consecutive frames'
errors are correlated, so the band does not apply to one sequence's time
average (docs/decisions/nees-over-independent-runs.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2
from tqdm import tqdm

from graphtrack.detect.base import POLAR_MODELS, Observation
from graphtrack.estimate.graph import left_error
from graphtrack.io.frame import Frame


@dataclass
class NeesResult:
    """values (R,): one NEES per run; mean; band: the 95 % band of the mean; inside."""

    values: np.ndarray
    mean: float
    band: tuple[float, float]

    @property
    def inside(self) -> bool:
        return self.band[0] <= self.mean <= self.band[1]


def nees_band(runs: int, dof: int = 6, level: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the mean of ``runs`` independent chi2(dof) values."""
    a = 0.5 * (1.0 - level)
    lo, hi = chi2.ppf([a, 1.0 - a], dof * runs) / runs
    return float(lo), float(hi)


def _observation(f, model: str) -> Observation:
    if model in POLAR_MODELS:
        return Observation(model, lines=f.lines, markers=f.markers)
    return Observation(model, pixels=f.pixels, markers=f.markers)


def monte_carlo_nees(make, sequence, runs: int = 200, first: int = 60, last: int = 200, seed: int = 0,
                     prior_std=None, walk_sigma=(2.5e-5, 1e-4), model: str = "line-intensities",
                     progress: bool = False, **observe_kw) -> NeesResult:
    """Monte-Carlo NEES of the estimators built by ``make(ctx)`` (a fresh one per run).

    Run r: ``sequence(n, seed=..., walk_sigma=..., **observe_kw)`` -> a Sequence
    (ctx, frames, right_frames), the synthetic world's
    (:func:`graphtrack.sim.synthetic.sequence`; passed in, as eval sits below
    sim), with n = k_r + 1 and seed ``seed + 1 + r``, the sequence's default hand-eye error (4.1 mm / 1.6 deg)
    or, with ``prior_std`` = (m, rad), one drawn from N(0, diag(prior_std^2)),
    the true E following the random walk ``walk_sigma`` (m, rad per frame),
    observed with ``observe_kw`` (pixel_noise, marker_noise, pixels_per_edge,
    ...); scored at one frame k_r ~ U[first, last). The sequence's ``ctx`` is each
    estimator's context and its ``right_frames`` (None: mono; a list from
    :func:`graphtrack.sim.synthetic.stereo_sequence`) the right image's observations.
    """
    pick = np.random.default_rng(seed)
    values = []
    for r in tqdm(range(runs), desc="NEES runs", disable=not progress, leave=False):
        k_r = int(pick.integers(first, last))
        if prior_std is not None:
            observe_kw["handeye_error"] = pick.standard_normal(6) * np.repeat(np.asarray(prior_std, float), 3)
        seq = sequence(k_r + 1, seed=seed + 1 + r, walk_sigma=walk_sigma, **observe_kw)
        frames, right = seq.frames, seq.right_frames
        est = make(seq.ctx)
        for i, f in enumerate(frames):
            fr = Frame(f.index, f.stamp, None, f.q[:6], f.q[6])
            e = (est.step(fr, _observation(f, model)) if right is None
                 else est.step(fr, _observation(f, model), _observation(right[i], model)))
        x = left_error(frames[-1].E_true, e.E)
        values.append(float(x @ np.linalg.solve(e.cov, x)))
    v = np.array(values)
    return NeesResult(v, float(v.mean()), nees_band(runs))
