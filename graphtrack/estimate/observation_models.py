"""Observation log-likelihoods log P(z_t | E) for all particles at once.

Each function returns an (N,) array, up to a constant shared by all particles.
Inputs per particle n: the projected limb lines (rho_nj, theta_nj), j = 1, 2 (px,
rad; :func:`graphtrack.robot.features.shaft_lines`), their ``valid`` flag and the
projected markers (px); detections are undistorted px (:class:`graphtrack.detect.base.Observation`).

Polar models (``canny``, ``*-polar``), gamma_rho 1/px, gamma_theta 1/rad:

    log P = max_pi log sum_i exp(-gamma_rho |rho_i^det - rho_pi(i)(E)| - gamma_theta |theta_i^det - theta_pi(i)(E)|)

pi an injective pairing of detected lines to limbs (both tried, or ``edge_ids``),
differences by :func:`graphtrack.geometry.lines.line_difference`.
Pixel models (``endpoint-intensities``, ``line-intensities``): pixel p = (x, y) has
R = cos(theta) x + sin(theta) y - rho (px) against the NEARER limb, R ~ N(0, sigma^2),

    log P = lambda sum_p w_p max(-R_p^2 / (2 sigma^2), -c^2 / 2),   w_p = min(1, n / m)

(the floor: a Gaussian + uniform outlier max-mixture; lambda = ``pixel_weight``;
n = ``pixel_effective_count`` per m-pixel edge set, 0: w_p = 1), times ``band_weight``
b for the pixels of a set the observation marks a band (``Observation.bands``:
the learned net's heatmap band, not moved onto the image's edge), as if their
sigma were sigma / sqrt(b) inside the floor.
Markers: log P = -sum_k cost(min(d_k, gate)), d_k (px) to the associated projected
marker; cost "laplace" gamma d, "huber" u^2/2 up to u = k then k u - k^2/2 (u = d/s),
"cauchy" log(1 + u^2), "laplace+cauchy" gamma d + log(1 + u^2) (the particle filter's
update: the paper's Laplace, whose constant pull out to the gate brings in a cloud still
tens of px off, plus a core at the factor graph's marker scale s = 2 px, so that a marker a
few px off costs what the detector's accuracy says; docs/decisions/pf-marker-core.md);
the best injective assignment per particle (all enumerated), markers facing away count as
unmatched (cost gate).
Shaft end (``Observation.shaft_end``: the detected end p and the unit direction d
along the shaft's image): s = d . (pi(P(E)) - p) px, P the end rim's front point
(:mod:`graphtrack.geometry.shaft_end`),

    log P = max(-s^2 / (2 sigma_e^2), -c_e^2 / 2)

(sigma_e = ``END_SIGMA``, c_e = ``END_OUTLIER_SIGMAS``: a step from dark to bright
that is not the shaft's end, a crossing flap or instrument, costs at most c_e^2 / 2).
Degenerate projections (valid False) get ``INVALID_LOGLIK``.

Defaults and their measurements: docs/decisions/pixel-effective-count.md, marker-gate.md,
band-weight.md.
"""
from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np
from scipy.optimize import linear_sum_assignment

from graphtrack.detect.base import OBSERVATION_MODELS, POLAR_MODELS
from graphtrack.estimate.pf.pixel_model import (PIXEL_OUTLIER_SIGMAS, PIXEL_SIGMA,  # noqa: F401
                                                PIXEL_WEIGHT, pixel_loglik)
from graphtrack.geometry.lines import line_difference

#: log-likelihood of a particle whose shaft projection is degenerate (finite).
INVALID_LOGLIK = -1.0e6

#: Defaults (units in the names): polar Laplace rates, pixel sigma, marker model.
GAMMA_RHO = 0.5        # 1/px: 2 px of rho error costs 1 nat
GAMMA_THETA = 50.0     # 1/rad: 0.02 rad (1.15 deg) of theta error costs 1 nat
#: per edge (0: every pixel counts once): pf, smoother, batch; docs/decisions/pixel-effective-count.md
PIXEL_EFFECTIVE_COUNT = 10.0
SEARCH_PIXEL_EFFECTIVE_COUNT = 30.0  # the search's default (the smoother's; the pf passes its own n)
#: weight of a heatmap band's pixels (Observation.bands) in the estimators: the particle
#: filter's likelihood and search, the smoother's and batch's pixel factors: 1/4, i.e. twice
#: the pixel sigma (the bands lie up to ~4 px off); the smoother's search keeps 1 (measured
#: worse at 1/4); docs/decisions/band-weight.md
BAND_WEIGHT = 0.25
SEARCH_BAND_WEIGHT = 1.0
MARKER_GAMMA = 0.15    # 1/px, per marker (the laplace losses)
MARKER_GATE = 50.0     # px (paper: 20); docs/decisions/marker-gate.md
MARKER_LOSS = "laplace"  # the start-up searches and the divergence monitor
PF_MARKER_LOSS = "laplace+cauchy"   # the particle filter's update; docs/decisions/pf-marker-core.md
MARKER_SIGMA = 2.0     # px (huber and the cauchy losses; the factor graph's marker sigma)
MARKER_HUBER_K = 2.0   # Huber threshold in units of MARKER_SIGMA
MARKER_LOSSES = ("laplace", "huber", "cauchy", "laplace+cauchy")
END_SIGMA = 2.0        # px along the shaft's image; docs/decisions/shaft-end.md
END_OUTLIER_SIGMAS = 3.0


def _finite_rows(a: np.ndarray, width: int) -> np.ndarray:
    a = np.asarray(a, dtype=float).reshape(-1, width)
    return a[np.all(np.isfinite(a), axis=1)]


def polar_loglik(rho: np.ndarray, theta: np.ndarray, lines: np.ndarray,
                 gamma_rho: float = GAMMA_RHO, gamma_theta: float = GAMMA_THETA,
                 edge_ids: np.ndarray | None = None) -> np.ndarray:
    """Polar model over particles: rho, theta (N, 2) projected; lines (k, 2) detected.

    Returns (N,); zeros when no line is detected.
    """
    lines = np.asarray(lines, dtype=float).reshape(-1, 2)
    keep = np.all(np.isfinite(lines), axis=1)
    ids = None if edge_ids is None or len(edge_ids) != len(lines) else np.asarray(edge_ids)[keep]
    lines = lines[keep]
    n = rho.shape[0]
    k = len(lines)
    if k == 0:
        return np.zeros(n)
    # cost[n, i, j]: detected line i against projected edge j
    drho, dth = line_difference(lines[None, :, None, 0], lines[None, :, None, 1],
                                rho[:, None, :], theta[:, None, :])
    cost = gamma_rho * np.abs(drho) + gamma_theta * np.abs(dth)
    if ids is not None and np.all((ids >= 0) & (ids < rho.shape[1])):
        pairings = [tuple(int(j) for j in ids)]
    elif k <= rho.shape[1]:
        pairings = list(itertools.permutations(range(rho.shape[1]), k))
    else:  # more detections than edges: each takes its best edge
        return _logsumexp(-cost.min(axis=2), axis=1)
    best = None
    rows = np.arange(k)
    for p in pairings:
        ll = _logsumexp(-cost[:, rows, list(p)], axis=1)
        best = ll if best is None else np.maximum(best, ll)
    return best


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return (m + np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True))).squeeze(axis)


@lru_cache(maxsize=64)
def _assignments(n_model: int, n_det: int) -> np.ndarray:
    """All injective maps detected -> model, as (A, n_det) model indices, -1 = unmatched
    (only when n_det > n_model)."""
    if n_det <= n_model:
        return np.array(list(itertools.permutations(range(n_model), n_det)), dtype=int).reshape(-1, n_det)
    rows = []
    for chosen in itertools.permutations(range(n_det), n_model):
        r = -np.ones(n_det, dtype=int)
        r[list(chosen)] = np.arange(n_model)
        rows.append(r)
    return np.unique(np.array(rows, dtype=int), axis=0)


@lru_cache(maxsize=64)
def _assignment_matrix(n_model: int, n_det: int) -> np.ndarray:
    """One-hot (n_det * M', A) matrix of :func:`_assignments` (M' = n_model, plus
    one "unmatched" column when n_det > n_model): column a selects entry
    (k, model index of k under a) of a flattened (n_det, M') cost table."""
    a = _assignments(n_model, n_det)
    width = n_model + (1 if n_det > n_model else 0)
    a = np.where(a < 0, n_model, a)
    H = np.zeros((n_det * width, len(a)))
    for k in range(n_det):
        H[k * width + a[:, k], np.arange(len(a))] = 1.0
    return H


MAX_ENUMERATED = 720


def marker_cost(d: np.ndarray, loss: str = MARKER_LOSS, gamma: float = MARKER_GAMMA,
                sigma: float = MARKER_SIGMA, huber_k: float = MARKER_HUBER_K) -> np.ndarray:
    """Cost in nats of a (gated) marker distance d (px): see the module docstring."""
    if loss == "laplace":
        return gamma * d
    u = d / sigma
    if loss == "huber":
        return np.where(u <= huber_k, 0.5 * u * u, huber_k * u - 0.5 * huber_k * huber_k)
    if loss == "cauchy":
        return np.log1p(u * u)
    if loss == "laplace+cauchy":
        return gamma * d + np.log1p(u * u)
    raise ValueError(f"unknown marker loss {loss!r} (choose from {', '.join(MARKER_LOSSES)})")


def _gated_cost(d2: np.ndarray, loss: str, gamma: float, sigma: float, huber_k: float) -> np.ndarray:
    """:func:`marker_cost` of the distances sqrt(d2), overwriting d2 (the particle filter's
    loss without a temporary per operation: it runs on every particle, marker and detection)."""
    if loss != "laplace+cauchy":
        return marker_cost(np.sqrt(d2, out=d2), loss, gamma, sigma, huber_k)
    c = np.sqrt(d2)
    c *= gamma
    d2 *= 1.0 / (sigma * sigma)
    c += np.log1p(d2, out=d2)
    return c


def marker_loglik(projected: np.ndarray, visible: np.ndarray, detected: np.ndarray,
                  gamma: float = MARKER_GAMMA, gate: float = MARKER_GATE,
                  estimate_index: int | None = None, loss: str = MARKER_LOSS,
                  sigma: float = MARKER_SIGMA, huber_k: float = MARKER_HUBER_K) -> np.ndarray:
    """Marker model: projected (N, M, 2) px, visible (N, M) bool, detected (D, 2) px.

    Per particle, min over assignments of sum_k c(min(d_k, gate)), negated, with
    c the marker ``loss`` (laplace: gamma d; huber / cauchy / laplace+cauchy: see marker_cost).
    When the assignments are too many to enumerate (> MAX_ENUMERATED) the
    Hungarian assignment at particle ``estimate_index`` (default 0) is used
    for all particles. (:func:`marker_loglik_mn` takes the particle-last layout.)
    """
    projected = np.asarray(projected, float)
    return marker_loglik_mn(projected[..., 0].T, projected[..., 1].T, np.asarray(visible).T,
                            detected, gamma, gate, estimate_index, loss, sigma, huber_k)


def marker_loglik_mn(u: np.ndarray, v: np.ndarray, visible: np.ndarray, detected: np.ndarray,
                     gamma: float = MARKER_GAMMA, gate: float = MARKER_GATE,
                     estimate_index: int | None = None, loss: str = MARKER_LOSS,
                     sigma: float = MARKER_SIGMA, huber_k: float = MARKER_HUBER_K) -> np.ndarray:
    """:func:`marker_loglik` with the projected markers as u, v (M, N) px and visible (M, N)."""
    detected = _finite_rows(detected, 2)
    M, n = u.shape
    D = len(detected)
    if D == 0 or M == 0:
        return np.zeros(n)
    d2 = u[None] - detected[:, 0, None, None]           # (D, M, N), squared distances in place
    dy = v[None] - detected[:, 1, None, None]
    d2 *= d2
    dy *= dy
    d2 += dy
    np.fmin(d2, gate * gate, out=d2)                     # fmin: NaN -> gate
    np.copyto(d2, gate * gate, where=~np.asarray(visible, bool)[None])
    dist = _gated_cost(d2, loss, gamma, sigma, huber_k)
    gate = float(marker_cost(np.float64(gate), loss, gamma, sigma, huber_k))
    count = 1
    for i in range(min(M, D)):
        count *= max(M, D) - i
    if count <= MAX_ENUMERATED:
        if D > M:  # row M of each table = unmatched (cost gate)
            dist = np.concatenate([dist, np.full((D, 1, n), gate)], axis=1)
        # cost of every assignment at once: one-hot (A, D*M') . (D*M', N)
        cost = _assignment_matrix(M, D).T @ dist.reshape(-1, n)
        total = cost.min(axis=0)
    else:
        i0 = 0 if estimate_index is None else estimate_index
        r, c = linear_sum_assignment(dist[:, :, i0])
        total = dist[r, c].sum(axis=0) + gate * (D - len(r))
    return -total


def shaft_end_loglik(end_u: np.ndarray | None, end_v: np.ndarray | None, observation,
                     sigma: float = END_SIGMA, outlier_sigmas: float = END_OUTLIER_SIGMAS) -> np.ndarray | float:
    """The shaft-end term (module doc) for projected ends (N,) px; 0 without a detected
    end or a modelled one. A hypothesis whose end is behind the camera (NaN) gets the floor."""
    end = np.asarray(observation.shaft_end, float).reshape(-1, 4)
    if end_u is None or len(end) == 0:
        return 0.0
    p, d = end[0, :2], end[0, 2:]
    z = (d[0] * (end_u - p[0]) + d[1] * (end_v - p[1])) / sigma
    return np.fmax(-0.5 * z * z, -0.5 * outlier_sigmas * outlier_sigmas)


def set_weight(m: int, band: bool, effective_count: float, band_weight: float) -> float:
    """The weight of each pixel of an m-pixel edge set: min(1, n / m) (n = ``effective_count``;
    1 when n <= 0), times ``band_weight`` for a band (``Observation.bands``). The particle
    filter's likelihood and the factor graph's pixel factors both weigh sets by it."""
    w = min(1.0, effective_count / m) if effective_count and effective_count > 0 else 1.0
    return w * band_weight if band else w


def _set_weights(sets: list, bands: list, effective_count: float, band_weight: float) -> np.ndarray | None:
    """Per-pixel weights (P,) of ``sets`` with their band flags (:func:`set_weight`); None when
    every weight is 1."""
    per_set = [set_weight(len(p), b, effective_count, band_weight) for p, b in zip(sets, bands)]
    if all(w == 1.0 for w in per_set):
        return None
    return np.concatenate([np.full(len(p), w) for p, w in zip(sets, per_set)])


def shaft_loglik(observation, rho: np.ndarray, theta: np.ndarray, valid: np.ndarray,
                 gamma_rho: float = GAMMA_RHO, gamma_theta: float = GAMMA_THETA,
                 use_edge_ids: bool = False, pixel_sigma: float = PIXEL_SIGMA,
                 pixel_outlier_sigmas: float = PIXEL_OUTLIER_SIGMAS,
                 pixel_weight: float = PIXEL_WEIGHT, _buffers: dict | None = None,
                 pixel_effective_count: float = PIXEL_EFFECTIVE_COUNT,
                 cos_sin: tuple | None = None, band_weight: float = 1.0) -> np.ndarray:
    """The shaft term for ``observation.model`` over particles (N,).

    rho, theta (N, 2): projected edges (px, rad). ``cos_sin``: their
    (cos theta, sin theta) if the caller has them; theta may then be a
    callable returning theta, evaluated only by the polar models.

    Pixel models with ``pixel_effective_count`` n > 0: the pixels of an edge
    set of m pixels each count min(1, n / m) (the edge is worth at most n
    independent pixels), times ``pixel_weight``. Whatever n, a set the
    observation marks a band (``observation.bands``) counts ``band_weight``
    times that.

    Zeros (weights unchanged) when the frame has no shaft detection;
    INVALID_LOGLIK for particles with ``valid`` False.
    """
    model = observation.model
    if model not in OBSERVATION_MODELS:
        raise ValueError(f"unknown observation model {model!r}")
    n = rho.shape[0]
    if model in POLAR_MODELS:
        if len(observation.lines) == 0:
            return np.zeros(n)
        ids = observation.edge_ids if use_edge_ids and len(observation.edge_ids) else None
        ll = polar_loglik(rho, theta() if callable(theta) else theta, observation.lines,
                          gamma_rho, gamma_theta, ids)
    else:
        pairs = [(np.asarray(p, float).reshape(-1, 2), b)
                 for p, b in zip(observation.pixels, observation.pixel_bands) if len(p)]
        if not pairs:
            return np.zeros(n)
        sets, bands = [p for p, _ in pairs], [b for _, b in pairs]
        pw = _set_weights(sets, bands, pixel_effective_count, band_weight)
        ll = pixel_loglik(rho, theta, sets[0] if len(sets) == 1 else np.concatenate(sets),
                          pixel_sigma, pixel_outlier_sigmas, pixel_weight, _buffers, pw, cos_sin)
    ll = np.where(valid & np.isfinite(ll), ll, INVALID_LOGLIK)
    return ll
