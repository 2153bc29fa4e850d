"""Global search over the prior of E for the start-up and re-initialisation of the
online estimators.

Problem. At start-up (or after a long gap) E is only known to lie within the
hand-eye prior, 10 mm / 5 deg off in practice; a local method (LM, iSAM2's
Gauss-Newton, a particle cloud drawn from a narrower spread) started there can
pair the wrong silhouette edges or markers and stay locked. The particle
filter's vectorised likelihood scores thousands of hypotheses of E per
millisecond, so the search scores hypotheses over the whole prior instead.

Method (annealed cross-entropy search). Hypotheses x = (b [m], w [rad]) are
left camera-frame corrections of the reference E_ref: E(x) = Exp(x) . E_ref
(:func:`graphtrack.geometry.se3.bw_to_matrix`, the particle filter's
parameterisation). Stage s = 0 .. S-1 draws ``n`` hypotheses from
N(mu_s, Sigma_s) (mu_0 = centre, Sigma_0 = diag(spread^2)), scores each with

    J(x) = sum_f log P_s(z_f | E(x)) - 1/2 |(x - prior_centre) / prior_spread|^2

(prior_centre and prior_spread default to the first stage's centre and spread;
the observation models of :mod:`graphtrack.estimate.observation_models`,
the particle filter's vectorised projection and likelihood, :class:`Scorer`), with the pixel sigma of stage s: ``sigmas`` px, coarse to fine, so
that a hypothesis 30 px off still sees the data's pull while a 2 px sigma
would put all its pixels at the outlier floor), keeps the best ``elite``
fraction and fits N(mu_{s+1}, Sigma_{s+1}) to it (inflated by ``inflate`` so
the cloud does not collapse before the finest stage). The best hypothesis of
the final stage and the elite's covariance are returned. Markers are
associated per hypothesis (all assignments), so a hypothesis cannot inherit a
wrong pairing.

Cost: S * n hypotheses (default 4 x 2048), ~10-30 ms on one core, run once at
start-up and at each re-initialisation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.estimate import observation_models as om
from graphtrack.estimate.pf.projection import Hypotheses, frame_geometry, project

#: pixel sigma (px) of each stage of the search, coarse to fine
SIGMAS = (12.0, 6.0, 3.0, 2.0)


@dataclass
class SearchResult:
    """x: (6,) best hypothesis (b m, w rad) relative to the reference E_ref;
    cov: (6, 6) covariance of the final elite; score: J(x) at the finest stage
    (log-likelihood + log-prior, nats); loglik: the log-likelihood part."""

    x: np.ndarray
    cov: np.ndarray
    score: float
    loglik: float


class Scorer:
    """log P(z | E(x)) of many hypotheses x (n, 6) for one frame: the particle
    filter's projection (:mod:`graphtrack.estimate.pf.projection`) and observation
    models (:mod:`graphtrack.estimate.observation_models`), at a given pixel sigma.

    ctx: the TrackingContext whose ``handeye`` is E_ref; markers: score detected
    markers; gate_scale: full-size pixels per detection pixel (multiplies
    marker_gate, px); options: the particle filter's likelihood keywords
    (``pixel_sigma`` is overridden per call when ``sigma`` is given).
    """

    def __init__(self, ctx, markers: bool = True, gate_scale: float = 1.0, **options):
        unknown = set(options) - set(_LIKELIHOOD_OPTIONS)
        if unknown:
            raise TypeError(f"unknown likelihood options {sorted(unknown)}")
        self.robot = ctx.robot
        self.K = np.asarray(ctx.camera.K, float)
        self.E_ref = np.asarray(ctx.handeye, float)
        self.markers = bool(markers)
        o = {**_LIKELIHOOD_OPTIONS, **options}
        self.shaft_options = {k: o[k] for k in _SHAFT_KEYS}
        self.marker_gamma = float(o["marker_gamma"])
        self.marker_gate = float(o["marker_gate"]) * float(gate_scale)
        self.marker_options = dict(loss=o["marker_loss"], sigma=float(o["marker_sigma"]),
                                   huber_k=float(o["marker_huber_k"]))
        self._buffers: dict = {}
        self._geometry = None

    def frame_geometry(self, q):
        """The frame's features mapped by E_ref (:func:`graphtrack.estimate.pf.projection.frame_geometry`),
        cached for the last q."""
        q = np.asarray(q, float)
        if self._geometry is None or self._geometry[0] != q.tobytes():
            self._geometry = (q.tobytes(), frame_geometry(self.robot, q, self.E_ref))
        return self._geometry[1]

    def loglik(self, h: Hypotheses, observation, sigma: float | None = None,
               estimate_index: int = 0) -> np.ndarray:
        """(n,) log-likelihood of projected hypotheses h; ``estimate_index``: the
        hypothesis whose marker pairing breaks ties (the particle filter's best)."""
        ll = np.zeros(len(h.valid))
        if observation is None:
            return ll
        if observation.has_shaft:
            opts = self.shaft_options if sigma is None else {**self.shaft_options, "pixel_sigma": sigma}
            ll += om.shaft_loglik(observation, h.rho.T, lambda: h.theta.T, h.valid, _buffers=self._buffers,
                                  cos_sin=(h.cos.T, h.sin.T), **opts)
        if self.markers and len(observation.markers):
            ll += om.marker_loglik_mn(h.u, h.v, h.visible, observation.markers, self.marker_gamma,
                                      self.marker_gate, estimate_index=estimate_index,
                                      **self.marker_options)
        end_sigma = om.END_SIGMA if sigma is None else max(om.END_SIGMA, sigma)
        return ll + om.shaft_end_loglik(h.end_u, h.end_v, observation, end_sigma)

    def __call__(self, q, observation, x: np.ndarray, sigma: float | None = None) -> np.ndarray:
        """Log-likelihood (n,) of one frame (reading q, observation) for hypotheses x (n, 6)."""
        h = project(self.frame_geometry(q), self.K, np.atleast_2d(np.asarray(x, float)))
        return self.loglik(h, observation, sigma)

    def with_floor(self, q, observation, x: np.ndarray, shift: float = 0.05,
                   sigma: float | None = None) -> tuple[float, float]:
        """(log P(z | E(x)), :meth:`floor` at x) in one projection and one likelihood call
        (the divergence monitor's per-frame cost), at pixel sigma ``sigma`` (None: the configured)."""
        x = np.asarray(x, float)
        X = np.stack([x, x])
        X[1, 0] += shift
        ll = self(q, observation, X, sigma)
        return float(ll[0]), float(ll[1])

    def floor(self, q, observation, x: np.ndarray | None = None, shift: float = 0.05) -> float:
        """log P(z | E) of a hypothesis that explains nothing: x (default the reference)
        moved ``shift`` m sideways in the camera frame (:mod:`graphtrack.estimate.divergence`)."""
        x = np.zeros(6) if x is None else np.asarray(x, float).copy()
        x[0] += shift
        return float(self(q, observation, x[None])[0])


_SHAFT_KEYS = ("gamma_rho", "gamma_theta", "use_edge_ids", "pixel_sigma", "pixel_outlier_sigmas",
               "pixel_weight", "pixel_effective_count", "band_weight")
#: the particle filter's likelihood keywords and the search's defaults (the particle
#: filter's, except pixel_effective_count and band_weight, used where the caller passes
#: none: the smoother; the particle filter passes its own; docs/decisions/pixel-effective-count.md,
#: band-weight.md)
_LIKELIHOOD_OPTIONS = dict(gamma_rho=om.GAMMA_RHO, gamma_theta=om.GAMMA_THETA, use_edge_ids=False,
                           pixel_sigma=om.PIXEL_SIGMA, pixel_outlier_sigmas=om.PIXEL_OUTLIER_SIGMAS,
                           pixel_weight=om.PIXEL_WEIGHT, pixel_effective_count=om.SEARCH_PIXEL_EFFECTIVE_COUNT,
                           band_weight=om.SEARCH_BAND_WEIGHT,
                           marker_gamma=om.MARKER_GAMMA, marker_gate=om.MARKER_GATE,
                           marker_loss=om.MARKER_LOSS, marker_sigma=om.MARKER_SIGMA,
                           marker_huber_k=om.MARKER_HUBER_K)


def global_search(score, centre: np.ndarray, spread: np.ndarray, rng: np.random.Generator,
                  n: int = 2048, sigmas=SIGMAS, elite: float = 0.03, inflate: float = 1.5,
                  prior_centre: np.ndarray | None = None, prior_spread: np.ndarray | None = None,
                  incumbent: np.ndarray | None = None, first_cov: np.ndarray | None = None) -> SearchResult:
    """Annealed cross-entropy search (module doc).

    score(x, sigma) -> (n,) log-likelihood of hypotheses x (n, d) at pixel sigma (d = 6:
    the pose (b, w); more: further parameters the score reads, as the particle filter's
    width offset); centre (d,), spread (d,): the first stage draws from N(centre, diag(spread^2));
    the prior term of J is N(prior_centre, diag(prior_spread^2)) (defaults: centre and
    spread; the re-initialisations search around the current estimate under the
    hand-eye prior); incumbent: a hypothesis scored in the first stage too (later
    stages re-score the best so far); first_cov (d, d): the first stage's covariance
    instead of diag(spread^2) (spread still floors the elite's covariance).
    """
    mu = np.asarray(centre, float).copy()
    centre = mu.copy() if prior_centre is None else np.asarray(prior_centre, float)
    spread = np.asarray(spread, float)
    prior_spread = spread if prior_spread is None else np.asarray(prior_spread, float)
    L = np.diag(spread) if first_cov is None else np.linalg.cholesky(np.asarray(first_cov, float))
    n_elite = max(8, int(round(elite * n)))
    best = None if incumbent is None else np.asarray(incumbent, float)
    for s, sigma in enumerate(sigmas):
        x = mu + rng.standard_normal((n, len(mu))) @ L.T
        if best is not None:
            x[0] = best                      # the incumbent is re-scored at this sigma
        ll = np.asarray(score(x, sigma), float)
        J = ll - 0.5 * np.sum(((x - centre) / prior_spread) ** 2, axis=1)
        J = np.where(np.isfinite(J), J, -np.inf)
        order = np.argsort(-J)[:n_elite]
        top = x[order]
        best = top[0].copy()
        mu = top.mean(axis=0)
        C = np.cov(top.T) + np.diag((1e-3 * spread) ** 2)
        if s < len(sigmas) - 1:
            L = np.linalg.cholesky(inflate ** 2 * 0.5 * (C + C.T))
    return SearchResult(best, C, float(J[order[0]]), float(ll[order[0]]))
