"""Divergence detection: a windowed normalised-misfit test on the observations.

Per informative frame t the estimator's current estimate x_t is scored with the
observation models (:class:`graphtrack.estimate.startup.Scorer`):
l_t = log P(z_t | x_t), and so is a reference hypothesis that explains nothing
(the estimate shifted 5 cm sideways, every pixel and marker at its outlier
floor): f_t. The misfit

    m_t = clip(l_t / f_t, 0, 1)

is ~0 when the detections sit on the projection (a 1 px residual with the 2 px
pixel sigma and 3 sigma floor: 0.03) and ~1 when none does (a wrong pairing of
edges, a lock on a tissue edge). The monitor fires when the mean of m_t over the
last ``window`` informative frames exceeds ``threshold``. It only requests a
search: the caller re-initialises only if the search finds a pose that explains
the frame better by a likelihood-ratio margin (:mod:`graphtrack.estimate.reinit`),
so a false alarm (partial occlusion, stray edges) costs one search and
nothing else.
"""
from __future__ import annotations

from collections import deque

import numpy as np

#: the alarm rate per informative frame the monitor is designed to stay under on a
#: correct lock (window 10, threshold 0.5; tests/test_estimate_robust.py checks it)
NOMINAL_FALSE_ALARM_RATE = 0.01

#: log-likelihoods below this are the observation models' INVALID_LOGLIK (degenerate)
_INVALID = -1e5


def misfit(loglik: float, floor: float) -> float:
    """m = clip(loglik / floor, 0, 1); NaN when either is degenerate or floor >= 0."""
    if not (np.isfinite(loglik) and np.isfinite(floor)) or floor >= 0 or loglik < _INVALID or floor < _INVALID:
        return float("nan")
    return float(np.clip(loglik / floor, 0.0, 1.0))


class DivergenceMonitor:
    """Windowed misfit test (module doc). ``update(loglik, floor)`` -> fired (bool)."""

    def __init__(self, window: int = 10, threshold: float = 0.5):
        self.window = int(window)
        self.threshold = float(threshold)
        self.values: deque = deque(maxlen=self.window)
        self.fired = 0

    def reset(self) -> None:
        self.values.clear()

    def update(self, loglik: float, floor: float) -> bool:
        return self.update_misfit(misfit(loglik, floor))

    def update_misfit(self, m: float) -> bool:
        """Add one frame's misfit (NaN: not counted); True when the window's mean exceeds the threshold."""
        if np.isfinite(m):
            self.values.append(m)
        if len(self.values) < self.window or np.mean(self.values) <= self.threshold:
            return False
        self.fired += 1
        self.values.clear()
        return True
