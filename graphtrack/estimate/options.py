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
#: the pf's and smoother's start-up search and re-initialisation: spread of its hypotheses
#: (and of the prior region it keeps estimates in), m and rad (docs/decisions/startup-search.md)
SEARCH_STD_B = 6e-3
SEARCH_STD_W = 0.05
#: the particle filter's initial cloud: stds, m and rad (pf-initial-spread-and-roughening.md)
INIT_STD_B = 4e-3
INIT_STD_W = 0.03
#: the largest hand-eye sigma accepted (m, rad): beyond it the tool would not be in view
MAX_HANDEYE_SIGMA = (0.1, np.radians(30.0))


@dataclass(frozen=True)
class EstimatorOptions:
    """particles and seed (its resampling draws): pf; lag (s) and smoother: the
    fixed-lag smoother; edge_bias: the edge-bias state of the smoother and the batch
    (off for edges known to be unbiased); tuned: further constructor keywords of
    the chosen estimator (e.g. a tuned set of its constants), passed as they are;
    search: the pf's and the smoother's global start-up search, divergence monitor
    and re-initialisation (:mod:`graphtrack.estimate.reinit`) and the pf's window
    move (:mod:`graphtrack.estimate.pf.window_move`); off: the local start-up of
    before, for comparisons; handeye_sigma (sigma_b m, sigma_w rad): how far the
    recording's handeye.yaml may be off, per axis (1 sigma) of the lumped error's
    translation and rotation; None: (PRIOR_SIGMA_B, PRIOR_SIGMA_W). It is the smoother's
    and batch's hand-eye prior, and scales the search's spread and the particle
    filter's initial cloud by the same factors (docs/decisions/handeye-sigma.md)."""

    particles: int = PARTICLES
    seed: int = 0
    lag: float = LAG_S
    smoother: str = SMOOTHER
    edge_bias: bool = True
    search: bool = SEARCH
    handeye_sigma: tuple[float, float] | None = None
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
        if self.handeye_sigma is not None:
            check_handeye_sigma(self.handeye_sigma)
        return self

    @property
    def prior_sigma(self) -> tuple[float, float]:
        """(sigma_b m, sigma_w rad) of the hand-eye prior these options give."""
        return (PRIOR_SIGMA_B, PRIOR_SIGMA_W) if self.handeye_sigma is None else \
            (float(self.handeye_sigma[0]), float(self.handeye_sigma[1]))

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
        if self.handeye_sigma is not None:
            kw.update(prior_keywords(estimator, *self.prior_sigma))
        return {**kw, **self.tuned}


def prior_keywords(estimator: str, sigma_b: float, sigma_w: float) -> dict:
    """The constructor keywords that put ``estimator``'s hand-eye prior at (sigma_b m,
    sigma_w rad) per axis: the smoother's and batch's prior itself; the search's spread
    (pf, smoother, and the batch's online smoother) and the particle filter's initial
    cloud scaled from their defaults by sigma_b / PRIOR_SIGMA_B and sigma_w / PRIOR_SIGMA_W."""
    fb, fw = sigma_b / PRIOR_SIGMA_B, sigma_w / PRIOR_SIGMA_W
    kw = {}
    if estimator in ("smoother", "batch"):
        kw.update(prior_sigma_b=sigma_b, prior_sigma_w=sigma_w)
    if estimator in ("pf", "smoother", "batch"):
        kw.update(search_std_b=SEARCH_STD_B * fb, search_std_w=SEARCH_STD_W * fw)
    if estimator == "pf":
        kw.update(init_std_b=INIT_STD_B * fb, init_std_w=INIT_STD_W * fw)
    return kw


def check_handeye_sigma(sigma) -> tuple[float, float]:
    """(sigma_b m, sigma_w rad) as floats, or InputError naming --handeye-sigma (given in mm, deg)."""
    try:
        b, w = (float(v) for v in sigma)
    except (TypeError, ValueError):
        raise InputError(f"--handeye-sigma takes two numbers, mm and deg, got {sigma!r}") from None
    hi_b, hi_w = MAX_HANDEYE_SIGMA
    if not (np.isfinite(b) and np.isfinite(w) and 0 < b <= hi_b and 0 < w <= hi_w):
        raise InputError(f"--handeye-sigma must be in (0, {hi_b * 1e3:g}] mm and (0, {np.degrees(hi_w):g}] deg, "
                         f"got {b * 1e3:g} mm, {np.degrees(w):g} deg")
    return b, w
