"""Total-least-squares line fits and the method's sequential RANSAC.

Lines are (rho, theta) of :mod:`graphtrack.geometry.lines`
(cos(theta) x + sin(theta) y = rho, theta in [0, pi), undistorted px).

Total least squares (TLS) of points p_j = (x_j, y_j), weights w_j: with the
weighted mean m and scatter C = sum_j w_j (p_j - m)(p_j - m)^T / sum_j w_j,
the line direction is C's principal eigenvector, at angle

    phi = 1/2 atan2(2 C_xy, C_xx - C_yy),

so the normal angle is theta = phi + pi/2 and rho = cos(theta) m_x + sin(theta) m_y.
This minimises sum_j w_j R(p_j | theta, rho)^2, R the pixel residual (px).

Sequential RANSAC (the method's defaults): repeat ``iterations`` = 5 times on
the points not yet explained: draw ``trials`` = 100 random minimal sets of
``samples`` = 3 pixels, fit each by TLS, count inliers |R| <= ``threshold`` =
0.75 px, keep the trial with most inliers, refit it by TLS on its inliers,
record (rho, theta) and the inlier count, and remove those inliers. All trials
of an iteration are evaluated at once (a (trials, points) residual matrix).

With ``groups`` (a 0 / 1 label per point: the two endpoint discs of E_e), each
sample takes its first pixel from group 0 and its second from group 1 while
both have points left, so every hypothesis spans the edge: a line fitted
inside one ~20 px disc follows the pixel lattice instead (it comes out at
multiples of pi / 4, tens of degrees off the edge; :mod:`graphtrack.detect.observe`
leaves an edge with an empty disc out).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from graphtrack.geometry.lines import canonical, pixel_residual


def tls_from_moments(n, sx, sy, sxx, sxy, syy) -> tuple[np.ndarray, np.ndarray]:
    """TLS line(s) from (weighted) raw moments, broadcasting over any shape.

    n = sum w, sx = sum w x, sxx = sum w x^2, ... Returns canonical (rho, theta).
    For numerical accuracy pass moments of coordinates centred near the points
    (then shift rho back, see :func:`fit_line_tls`). n must be > 0.
    """
    n = np.asarray(n, float)
    mx, my = sx / n, sy / n
    cxx = sxx / n - mx * mx
    cxy = sxy / n - mx * my
    cyy = syy / n - my * my
    phi = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    theta = phi + 0.5 * np.pi
    rho = np.cos(theta) * mx + np.sin(theta) * my
    return canonical(rho, theta)


def fit_line_tls(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Total-least-squares line (rho px, theta rad; canonical, :mod:`graphtrack.geometry.lines`)
    through points (P, 2) px, P >= 2, with optional weights (P,); NaNs without points."""
    p = np.asarray(points, float)
    w = np.ones(len(p)) if weights is None else np.asarray(weights, float)
    if len(p) == 0:
        return np.array([np.nan, np.nan])
    c = p.mean(0)
    q = p - c
    x, y = q[:, 0], q[:, 1]
    n = float(w.sum())
    if not n > 0 or not np.all(np.isfinite(c)):
        return np.array([np.nan, np.nan])          # no points, no weight, or a non-finite point
    # tls_from_moments and canonical for one line, in scalars (numpy's 0-d calls would cost
    # more than the arithmetic); np.arctan2, not math.atan2: the two differ in the last bit
    # on some CPUs, and the line stays the one tls_from_moments gives
    mx, my = float(w @ x) / n, float(w @ y) / n
    cxx = float(w @ (x * x)) / n - mx * mx
    cxy = float(w @ (x * y)) / n - mx * my
    cyy = float(w @ (y * y)) / n - my * my
    theta = 0.5 * float(np.arctan2(2.0 * cxy, cxx - cyy)) + 0.5 * math.pi
    if not math.isfinite(theta):
        return np.array([np.nan, np.nan])
    rho = math.cos(theta) * mx + math.sin(theta) * my
    k = math.floor(theta / math.pi)
    theta -= k * math.pi
    if k % 2 == 1:
        rho = -rho
    if theta >= math.pi:
        rho, theta = -rho, theta - math.pi
    rho = rho + math.cos(theta) * float(c[0]) + math.sin(theta) * float(c[1])
    return np.array([rho, theta])


@dataclass
class RansacConfig:
    """The method's sequential-RANSAC hyper-parameters (px, counts)."""

    iterations: int = 5      #: lines extracted one after another
    samples: int = 3         #: pixels per hypothesis (TLS fit of the sample)
    threshold: float = 0.75  #: inlier residual |R| (px)
    trials: int = 100        #: hypotheses per iteration
    min_inliers: int = 3     #: stop when the best hypothesis explains fewer


def seeded_rng(rng) -> np.random.Generator:
    """``rng`` itself when a Generator, else a Generator seeded with it (None: seed 0, so that
    RANSAC draws repeat run to run)."""
    return np.random.default_rng(0 if rng is None else rng)


def sequential_ransac(points: np.ndarray, config: RansacConfig | None = None,
                      rng=None, groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sequential RANSAC lines in a pixel set.

    points: (P, 2) pixel coordinates (x, y); rng: a numpy Generator or a seed
    (None: seed 0, so results are reproducible by default); groups: (P,) 0 / 1
    labels, samples span both groups (module docstring).
    Returns lines (L, 2) canonical (rho, theta) and inlier counts (L,) int,
    L <= config.iterations, in extraction order.
    """
    cfg = config or RansacConfig()
    gen = seeded_rng(rng)
    pts = np.asarray(points, float).reshape(-1, 2)
    fin = np.all(np.isfinite(pts), axis=1)
    pts = pts[fin]
    grp = None if groups is None else np.asarray(groups).reshape(-1)[fin]
    lines, counts = [], []
    if len(pts) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    centre = pts.mean(0)
    remaining = pts - centre  # centred for conditioning; rho shifted back at the end
    k = max(2, int(cfg.samples))
    for _ in range(int(cfg.iterations)):
        P = len(remaining)
        if P < max(k, cfg.min_inliers):
            break
        idx = gen.integers(0, P, size=(int(cfg.trials), k))
        if grp is not None:
            g0, g1 = np.flatnonzero(grp == 0), np.flatnonzero(grp == 1)
            if len(g0) and len(g1):  # first pixel from one endpoint disc, second from the other
                idx[:, 0] = g0[gen.integers(0, len(g0), int(cfg.trials))]
                idx[:, 1] = g1[gen.integers(0, len(g1), int(cfg.trials))]
        s = remaining[idx]                                   # (T, k, 2)
        c = s.mean(1, keepdims=True)
        q = s - c
        x, y = q[..., 0], q[..., 1]
        rho, theta = tls_from_moments(float(k), x.sum(1), y.sum(1), (x * x).sum(1),
                                      (x * y).sum(1), (y * y).sum(1))
        rho = rho + np.cos(theta) * c[:, 0, 0] + np.sin(theta) * c[:, 0, 1]
        # a sample with all pixels identical defines no line
        spread = (x * x + y * y).sum(1)
        r32 = remaining.astype(np.float32)   # pixel_residual in float32 on centred coordinates: ample, faster
        inl = np.abs(np.cos(theta).astype(np.float32)[:, None] * r32[None, :, 0]
                     + np.sin(theta).astype(np.float32)[:, None] * r32[None, :, 1]
                     - rho.astype(np.float32)[:, None]) <= cfg.threshold   # (T, P)
        score = np.where(spread > 1e-12, inl.sum(1), -1)
        best = int(np.argmax(score))
        if score[best] < cfg.min_inliers:
            break
        mask = inl[best]
        line = fit_line_tls(remaining[mask])
        # the refit may move the line: recount inliers against it, keep it if
        # it explains at least as many pixels (else keep the hypothesis)
        mask2 = np.abs(pixel_residual(remaining, line[:1], line[1:]))[0] <= cfg.threshold
        if mask2.sum() >= mask.sum():
            mask = mask2
        else:
            line = np.array([rho[best], theta[best]])
        lines.append(line)
        counts.append(int(mask.sum()))
        remaining = remaining[~mask]
        if grp is not None:
            grp = grp[~mask]
    if not lines:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    L = np.array(lines)
    rho = L[:, 0] + np.cos(L[:, 1]) * centre[0] + np.sin(L[:, 1]) * centre[1]
    rho, theta = canonical(rho, L[:, 1])
    return np.stack([rho, theta], 1), np.array(counts, dtype=int)


def best_line(points: np.ndarray, config: RansacConfig | None = None,
              rng=None, groups: np.ndarray | None = None) -> tuple[np.ndarray | None, int]:
    """The sequential-RANSAC line with the most inliers: ((rho, theta), count),
    or (None, 0) when the set holds too few pixels for any line."""
    lines, counts = sequential_ransac(points, config, rng, groups)
    if len(lines) == 0:
        return None, 0
    i = int(np.argmax(counts))
    return lines[i], int(counts[i])
