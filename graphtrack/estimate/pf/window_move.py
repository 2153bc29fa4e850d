"""The particle filter's window move: the cloud shifted to the mode of the frames since its start.

E changes by a random walk of 0.025 mm / 1e-4 rad per frame, so over the first few
dozen frames after a start it is all but constant, and the posterior of x given those
frames is

    p(x | z_1..z_k)  ~  N(x; 0, diag(s^2)) . prod_i P(z_i | E(x))

(s the hand-eye prior's spread, the search's). Along a direction the images barely see
(the slide of the tool along its shaft, the depth) each frame adds well under a nat,
and a cloud that has shrunk across that valley climbs it only as fast as its spread
lets resampling move it (docs/decisions/robustness-benchmark.md, traced on the tuning
recordings): the evidence is there, the particles are not.

The move, ``SCHEDULE`` frames (8 and 16) after each (re)start: a cross-entropy search of

    J(x) = sum_i log P(z_i | E(x)) - 1/2 |x / s|^2

over the frames since the start, from N(x_bar, diag(sd^2)), sd = max(3 std_cloud,
``floor``) per axis (x_bar, std_cloud: the cloud's weighted mean and spread), three
stages of ``n`` hypotheses, the elite's mean and covariance carried on. When the best
x* beats the cloud's mean by more than ``MIN_GAIN`` nats (Kass & Raftery's "strong"
evidence, 2 ln B > 6) every particle is shifted by x* - x_bar: the cloud keeps its
shape and weights, only its place changes. Nothing here reads anything but the
frames the filter has already used.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: nats: the window's mode must beat the cloud's mean by this much to move the cloud
MIN_GAIN = 3.0
#: frames used since a (re)start after which the cloud is moved (as the smoother's challenge)
SCHEDULE = (8, 16)


@dataclass
class WindowMode:
    """x (6,): the window's best hypothesis; gain: J(x) - J(x_bar) (nats)."""

    x: np.ndarray
    gain: float


def window_mode(objective, x_bar: np.ndarray, cloud_std: np.ndarray, floor: np.ndarray,
                rng: np.random.Generator, n: int = 512, stages: int = 3,
                elite: float = 0.03) -> WindowMode:
    """The mode of ``objective`` (x (m, 6) -> J (m,)) near x_bar (module doc)."""
    x_bar = np.asarray(x_bar, float)
    sd = np.maximum(3.0 * np.asarray(cloud_std, float), np.asarray(floor, float))
    L = np.diag(sd)
    mu, best = x_bar.copy(), x_bar.copy()
    n_elite = max(8, int(round(elite * n)))
    J0 = float(objective(x_bar[None])[0])
    J_best = J0
    for s in range(stages):
        x = mu + rng.standard_normal((n, 6)) @ L.T
        x[0] = best                                  # the incumbent competes at every stage
        J = np.asarray(objective(x), float)
        J = np.where(np.isfinite(J), J, -np.inf)
        order = np.argsort(-J)[:n_elite]
        if J[order[0]] > J_best:
            best, J_best = x[order[0]].copy(), float(J[order[0]])
        top = x[order]
        mu = top.mean(axis=0)
        if s < stages - 1:
            C = np.cov(top.T) + np.diag((1e-3 * sd) ** 2)
            L = np.linalg.cholesky(1.5 ** 2 * 0.5 * (C + C.T))
    return WindowMode(best, J_best - J0 if np.isfinite(J0) else np.inf)
