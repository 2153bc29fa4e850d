"""Particle weights in log space and low-variance (systematic) resampling.

Weights are kept as log weights ``logw`` (N,) normalised so that
logsumexp(logw) = 0; every normalisation subtracts the maximum first, so a
likelihood that is tiny for every particle never underflows to all-zero
weights (the best particle always keeps exp(0) = 1 before normalising).

Systematic resampling (Kitagawa 1996; "low-variance sampler", Thrun et al.,
Probabilistic Robotics, Table 4.4): one uniform u ~ U[0, 1/N) and the N
pointers u + k/N, k = 0..N-1, walk the cumulative weights. Particle i is
copied n_i times with |n_i - N w_i| < 1, so the weighted distribution is
preserved with the least resampling noise of the standard schemes.

Roughening by kernel shrinkage (Liu & West 2001), after resampling: with
bandwidth h, x_n <- a x_n + (1 - a) x_bar + N(0, h^2 Sigma), a = sqrt(1 - h^2),
which keeps the cloud's mean x_bar and covariance Sigma (a^2 + h^2 = 1).
"""
from __future__ import annotations

import numpy as np


def normalize_log_weights(logw: np.ndarray) -> np.ndarray:
    """Return logw - logsumexp(logw), robust to -inf / NaN entries.

    NaN entries count as -inf; if no entry is finite (nothing can be
    compared), the weights fall back to uniform.
    """
    logw = np.where(np.isnan(logw), -np.inf, np.asarray(logw, dtype=float))
    m = np.max(logw) if logw.size else -np.inf
    if not np.isfinite(m):
        # all -inf (or +inf): no information left -> uniform (or uniform on the +inf set)
        if m == np.inf:
            logw = np.where(logw == np.inf, 0.0, -np.inf)
            m = 0.0
        else:
            return np.full(logw.shape, -np.log(max(logw.size, 1)))
    z = logw - m
    return z - np.log(np.sum(np.exp(z)))


def weights_from_log(logw: np.ndarray) -> np.ndarray:
    """Normalised linear weights (sum 1) from (possibly unnormalised) log weights."""
    return np.exp(normalize_log_weights(logw))


def effective_sample_size(w: np.ndarray) -> float:
    """ESS = 1 / sum_i w_i^2 for normalised weights w (between 1 and N)."""
    w = np.asarray(w, dtype=float)
    return float(1.0 / np.sum(w * w))


def systematic_resample(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices (N,) of the particles to keep, by low-variance resampling.

    w: normalised weights (N,). One draw u ~ U[0, 1/N); pointer k sits at
    u + k/N and selects the first i with cumsum(w)[i] > pointer.
    """
    w = np.asarray(w, dtype=float)
    n = len(w)
    c = np.cumsum(w)
    c[-1] = 1.0  # guard against round-off leaving the last pointer unmatched
    pointers = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(c, pointers, side="right"), n - 1)


def shrink_and_jitter(x: np.ndarray, mean: np.ndarray, cov: np.ndarray, h: float, cap: np.ndarray,
                      floor: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Resampled particles x (N, d) roughened by kernel shrinkage (module doc) towards
    ``mean`` (d,) with jitter N(0, h^2 cov): the jitter's std capped per axis at ``cap``
    (d,) (along directions the data never constrain a cloud wider than the prior keeps
    only a^2 of its variance there), plus N(0, diag(floor^2)) so that it is never singular."""
    a = np.sqrt(max(1.0 - h ** 2, 0.0))
    x = a * x + (1.0 - a) * mean
    C = h ** 2 * np.asarray(cov, float)
    D = np.minimum(1.0, cap / np.sqrt(np.maximum(np.diag(C), 1e-300)))
    C = D[:, None] * C * D[None, :] + np.diag(np.asarray(floor, float) ** 2)
    L = np.linalg.cholesky(0.5 * (C + C.T))
    return x + rng.standard_normal(x.shape) @ L.T
