"""The estimator options that the CLI, the studies and the benchmarks choose, each
default written once here (the estimators' own tuned constants stay with them).

:class:`EstimatorOptions` holds them for any estimator; :meth:`EstimatorOptions.keywords`
hands each estimator the ones it takes.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from graphtrack.errors import InputError, check_seed, is_whole

PARTICLES = 1000      #: particle filter: particles
MAX_PARTICLES = 100_000  #: particle filter: the most particles accepted (about 0.2 s a frame, a few hundred MB)
LAG_S = 1.0           #: fixed-lag smoother: lag (s)
SMOOTHER = "isam2"    #: fixed-lag smoother: gtsam IncrementalFixedLagSmoother ("isam2") or Batch ("batch")
SMOOTHER_KINDS = ("isam2", "batch")
SEARCH = True         #: pf and smoother: global start-up search and re-initialisation (estimate/reinit.py)
#: the motion model of E shared by pf, smoother and batch: a random walk of the left (b, w)
#: per frame, MOTION_SIGMA_B m and MOTION_SIGMA_W rad (docs/methods/estimators.md)
MOTION_SIGMA_B = 2.5e-5
MOTION_SIGMA_W = 1e-4
#: the hand-eye prior of the smoother and batch: left (b, w) stds, m and rad
PRIOR_SIGMA_B = 5e-3
PRIOR_SIGMA_W = 0.035


@dataclass(frozen=True)
class EstimatorOptions:
    """particles and seed (its resampling draws): pf; lag (s) and smoother: the
    fixed-lag smoother; edge_bias: the edge-bias state of the smoother and the batch
    (off for edges known to be unbiased); tuned: further constructor keywords of
    the chosen estimator (e.g. a tuned set of its constants), passed as they are;
    search: the pf's and the smoother's global start-up search, divergence monitor
    and re-initialisation (:mod:`graphtrack.estimate.reinit`) and the pf's window
    move (:mod:`graphtrack.estimate.pf.window_move`); off: the local start-up of
    before, for comparisons."""

    particles: int = PARTICLES
    seed: int = 0
    lag: float = LAG_S
    smoother: str = SMOOTHER
    edge_bias: bool = True
    search: bool = SEARCH
    tuned: dict = field(default_factory=dict)

    def check(self) -> EstimatorOptions:
        """Raise InputError naming the CLI option of a value out of range; return self."""
        check_seed(self.seed)
        if not (is_whole(self.particles) and 0 < self.particles <= MAX_PARTICLES):
            raise InputError(f"--particles must be a whole number between 1 and {MAX_PARTICLES}, got {self.particles!r}")
        if isinstance(self.lag, bool) or not isinstance(self.lag, (int, float, np.number)) or \
                not (np.isfinite(self.lag) and self.lag > 0):
            raise InputError(f"--lag must be a positive finite number of seconds, got {self.lag!r}")
        if self.smoother not in SMOOTHER_KINDS:
            raise InputError(f"--smoother: choose from {', '.join(SMOOTHER_KINDS)}, not {self.smoother!r}")
        return self

    def keywords(self, estimator: str) -> dict:
        """The constructor keywords of ``estimator`` that these options set."""
        kw = {}
        if estimator == "pf":
            kw = {"particles": self.particles, "seed": self.seed}
        elif estimator == "smoother":
            kw = {"lag": self.lag, "smoother": self.smoother}
        if estimator in ("pf", "smoother"):
            kw["search"] = self.search
        if estimator == "pf" and not self.search:
            kw["window_move"] = False    # --no-search: the filter as it was before the search
        if estimator in ("smoother", "batch") and not self.edge_bias:
            kw["edge_bias"] = False
        return {**kw, **self.tuned}
