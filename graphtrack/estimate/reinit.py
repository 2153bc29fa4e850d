"""When and where an online estimator (re-)initialises: the global search of
:mod:`graphtrack.estimate.startup` at start-up, after a long stretch without
detections, and when :mod:`graphtrack.estimate.divergence` flags a lost lock.

:class:`SearchInit` is the smoother's policy object (the particle filter redraws
its cloud itself). ``propose(q, observation, E_current, informative)`` is called
once per frame and returns a new initial E (4x4) or None:

- the first informative frame (shaft or markers): the search over
  N(E_current, diag(spread^2)) (spread = (b m, w rad) per axis); its best
  mode is returned (start-up);
- an informative frame after ``gap`` or more frames without one, or when the
  divergence monitor fires: the same search around the current estimate; its
  mode is returned only when it explains the frame better than the current
  estimate by more than ``margin`` nats (a generalised likelihood-ratio test:
  a correct lock is kept, a wrong or lost one replaced).
"""
from __future__ import annotations

import numpy as np

from graphtrack.estimate.divergence import DivergenceMonitor
from graphtrack.estimate.startup import Scorer, global_search
from graphtrack.geometry.se3 import bw_to_matrix, invert, matrix_to_bw


class SearchInit:
    """Start-up / re-initialisation policy (module doc). ``count``: searches adopted."""

    def __init__(self, ctx, spread=(6e-3, 0.05), gap: int = 30, gate_scale: float = 1.0,
                 markers: bool = True, margin: float = 5.0, seed: int = 0, monitor: bool = True,
                 n: int = 2048, **scorer_options):
        b, w = spread
        self.spread = np.array([b] * 3 + [w] * 3, float)
        self.gap = int(gap)
        self.margin = float(margin)
        self.E_ref = np.asarray(ctx.handeye, float)
        self.scorer = Scorer(ctx, markers=markers, gate_scale=gate_scale, **scorer_options)
        self.n = int(n)
        self.rng = np.random.default_rng(seed)
        self.since = None            # informative frames: None before the first, else frames since
        self.count = 0
        self.result = None           # the adopted SearchResult (x relative to E_ref)
        self.monitor = DivergenceMonitor() if monitor else None

    def _x(self, E: np.ndarray) -> np.ndarray:
        return matrix_to_bw(np.asarray(E, float) @ invert(self.E_ref))

    def propose(self, q, observation, E_current: np.ndarray, informative: bool) -> np.ndarray | None:
        if not informative:
            if self.since is not None:
                self.since += 1
            return None
        first = self.since is None
        x_cur = self._x(E_current)
        ll_cur = None
        diverged = False
        if self.monitor is not None and not first:
            ll_cur = float(self.scorer(q, observation, x_cur[None])[0])
            diverged = self.monitor.update(ll_cur, self.scorer.floor(q, observation, x_cur))
        due = first or self.since >= self.gap or diverged
        self.since = 0
        if not due:
            return None
        res = global_search(lambda x, s: self.scorer(q, observation, x, s), x_cur, self.spread, self.rng,
                            n=self.n)
        if not first:
            if ll_cur is None:
                ll_cur = float(self.scorer(q, observation, x_cur[None])[0])
            if res.loglik < ll_cur + self.margin:
                return None
        if self.monitor is not None:
            self.monitor.reset()
        self.count += 1
        self.result = res
        return bw_to_matrix(res.x) @ self.E_ref
