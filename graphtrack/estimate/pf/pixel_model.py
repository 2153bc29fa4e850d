"""The method's pixel model over all particles at once (the pixel sets E_e / E_l).

Each pixel p = (x, y) of a shaft edge's pixel set has the residual

    R(p | theta, rho) = cos(theta) x + sin(theta) y - rho          (px)

(:func:`graphtrack.geometry.lines.pixel_residual`, here fused into one float32
product over all particles, edges and pixels: :func:`pixel_loglik`) against the NEARER of the two projected limb lines of a particle, R ~ N(0, sigma^2),
floored at c sigma (the max-mixture form of a Gaussian + uniform outlier mixture):

    log P = lambda * sum_p w_p max(-R_p^2 / (2 sigma^2), -c^2 / 2)

with lambda = ``weight`` and w_p the optional per-pixel weights (the per-edge
tempering of :func:`graphtrack.estimate.observation_models.shaft_loglik`).
See :mod:`graphtrack.estimate.observation_models` for how it is combined.
"""
from __future__ import annotations

import numpy as np

PIXEL_SIGMA = 2.0      # px
PIXEL_OUTLIER_SIGMAS = 3.0
PIXEL_WEIGHT = 1.0
#: particles per block of _floored_sq_sum: a (128, S) float32 block stays in the L2
#: cache through its four passes (0.45 -> 0.32 ms per 1000 particles x ~600 pixels, one core)
ROW_BLOCK = 128


def pixel_loglik(rho: np.ndarray, theta: np.ndarray, pixels: np.ndarray,
                 sigma: float = PIXEL_SIGMA, outlier_sigmas: float = PIXEL_OUTLIER_SIGMAS,
                 weight: float = PIXEL_WEIGHT, _buffers: dict | None = None,
                 pixel_weights: np.ndarray | None = None,
                 cos_sin: tuple | None = None) -> np.ndarray:
    """Pixel model over particles: rho, theta (N, L) projected edges, pixels (P, 2).

    ``pixel_weights`` (P,): an extra weight per pixel (the per-edge tempering
    of :func:`shaft_loglik`), applied inside the sum; None: all 1.
    ``cos_sin``: (cos theta, sin theta), each (N, L), when the caller has them
    (theta is then not read).

    Residuals R_{n,j}(p) = [cos theta, sin theta, -rho]_{n,j} . [x, y, 1]^T (px)
    are formed by one float32 matrix product on centred coordinates (exact to
    ~1e-4 px), squared, reduced over the edges by min (nearer edge), floored
    at (c sigma)^2 and summed over pixels. Returns (N,); zeros without pixels.

    Pruning (exact, same result): with a reference line r_j per edge, any
    particle's residual differs from the reference's by at most
    |R_{n,j}(p) - R_{r,j}(p)| <= max_n |d (cos, sin)| |p| + max_n |d rho|. A pixel
    whose bound puts edge j beyond c sigma for EVERY particle has its floored
    min decided without edge j, so once the cloud is tighter than the edges'
    separation most pixels are scored against one edge only (half the
    products), and pixels beyond the floor of every edge add (c sigma)^2.
    """
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    fin = np.all(np.isfinite(pixels), axis=1)
    if not np.all(fin):
        pixels = pixels[fin]
        if pixel_weights is not None:
            pixel_weights = np.asarray(pixel_weights, float)[fin]
    n, L = rho.shape
    P = len(pixels)
    if P == 0:
        return np.zeros(n)
    w = np.ones(P) if pixel_weights is None else np.asarray(pixel_weights, float).reshape(P)
    # centre the pixels: keeps float32 accurate for large coordinates
    c0 = pixels.mean(axis=0)
    pc = pixels - c0
    c, s = (np.cos(theta), np.sin(theta)) if cos_sin is None else cos_sin
    rho_c = rho - (c * c0[0] + s * c0[1])
    floor = (outlier_sigmas * sigma) ** 2
    groups = _edge_groups(c, s, rho_c, pc, outlier_sigmas * sigma)
    far = np.ones(P, bool)
    for _, cols in groups:
        far[cols] = False
    A = np.empty((n, L, 3), dtype=np.float32)
    A[..., 0], A[..., 1], A[..., 2] = c, s, -rho_c
    ssq = _floored_sq_sum(A.reshape(n, 3 * L), pc, w, groups, floor,
                          _buffers if _buffers is not None else {})
    return -weight * (ssq + floor * w[far].sum()) / (2.0 * sigma * sigma)


def _edge_groups(c: np.ndarray, s: np.ndarray, rho_c: np.ndarray, pc: np.ndarray,
                 dist: float) -> list:
    """Split centred pixels pc (P, 2) by the edges that may lie within ``dist`` px
    of them for some particle (the bound of :func:`pixel_loglik`), given the
    particles' edges cos theta, sin theta, rho_c (n, L) (rho_c: rho in centred
    coordinates).

    Returns [(edge indices, pixel indices), ...]; a pixel in no group is beyond
    ``dist`` of every edge for every particle. The reference line of edge j is
    the mid-range (c_r, s_r, rho_r) of the particles, so that
    |R_n(p) - R_r(p)| <= |(dc, ds)| |p| + |d rho| with |dc| <= ptp(c) / 2 etc.
    (a cloud straddling theta = 0 / pi has ptp(c) ~ 2: no pruning, still exact).
    One group with all edges when L != 2 or a line is not finite."""
    n, L = c.shape
    allp = np.arange(len(pc))
    if L != 2:
        return [(list(range(L)), allp)]
    # reduce along contiguous rows: numpy's axis-0 reduction of an (n, 2) array is ~15x slower
    X = np.concatenate([c.T, s.T, rho_c.T])  # (6, n)
    hi, lo = X.max(axis=1), X.min(axis=1)
    if not np.all(np.isfinite(hi - lo)):
        return [([0, 1], allp)]
    mid, half = 0.5 * (hi + lo), 0.5 * (hi - lo)
    dn = np.hypot(half[0:2], half[2:4])
    slack = np.hypot(pc[:, :1], pc[:, 1:]) * dn + half[4:6]  # (P, 2)
    r_ref = np.abs(pc[:, :1] * mid[0:2] + pc[:, 1:] * mid[2:4] - mid[4:6])
    reach = r_ref - slack < dist  # edge j may come within dist of the pixel
    near0, near1 = reach[:, 0], reach[:, 1]
    return [([0, 1], allp[near0 & near1]), ([0], allp[near0 & ~near1]),
            ([1], allp[near1 & ~near0])]


def _floored_sq_sum(A: np.ndarray, pc: np.ndarray, w: np.ndarray, groups: list,
                    floor: float, buf: dict) -> np.ndarray:
    """sum over groups, pixels p of a group: w_p min(min_{j in group} R_{n,j}(p)^2, floor).

    A (n, 3L) float32: [cos, sin, -rho_c] of each particle's edges; pc (P, 2)
    centred pixels. One product A . B with B (3L, S) block-sparse: column
    segment (group g, edge j) holds [x, y, 1] of g's pixels in rows 3j..3j+2,
    so every needed residual comes out of a single GEMM; the segments of a
    group are then reduced by min in place, ``ROW_BLOCK`` particles at a time.
    Large intermediates live in reused buffers: a fresh (n, S) array costs more
    in page faults than the arithmetic.
    """
    n = A.shape[0]
    segs = [(j, cols) for edges, cols in groups if len(cols) for j in edges]
    S = sum(len(cols) for _, cols in segs)
    if S == 0:
        return np.zeros(n)
    B = np.zeros((A.shape[1], S), dtype=np.float32)
    wt = np.zeros(S, dtype=np.float32)
    starts, o = [], 0
    for edges, cols in groups:
        if not len(cols):
            continue
        starts.append((o, len(cols), len(edges)))
        wt[o:o + len(cols)] = w[cols]
        for j in edges:
            B[3 * j, o:o + len(cols)] = pc[cols, 0]
            B[3 * j + 1, o:o + len(cols)] = pc[cols, 1]
            B[3 * j + 2, o:o + len(cols)] = 1.0
            o += len(cols)
    cap = buf.get("cap")
    if cap is None or len(cap) < S or cap[0] != np.float32(floor):
        cap = buf["cap"] = np.full(max(S, 1024), floor, dtype=np.float32)
    out = np.empty(n, dtype=np.float32)
    Rb = _buffer(buf, "R", min(n, ROW_BLOCK) * S).reshape(-1, S)
    for r0 in range(0, n, ROW_BLOCK):   # blocks of particles: R stays in the cache
        R = Rb[:min(n, r0 + ROW_BLOCK) - r0]
        np.matmul(A[r0:r0 + len(R)], B, out=R)
        with np.errstate(over="ignore"):  # absurd pixels overflow float32 to inf: floored below
            np.square(R, out=R)
        for o, m, k in starts:  # nearer edge: min over the group's segments, into its first
            for e in range(1, k):
                np.minimum(R[:, o:o + m], R[:, o + e * m:o + (e + 1) * m], out=R[:, o:o + m])
        np.minimum(R, cap[:S], out=R)  # an array operand: a scalar one is not vectorised (~5x slower)
        np.matmul(R, wt, out=out[r0:r0 + len(R)])
    return out.astype(np.float64)


def _buffer(buf: dict, key: str, size: int) -> np.ndarray:
    """A flat float32 scratch array of ``size`` elements, reused from buf when large enough."""
    a = buf.get(key)
    if a is None or a.size < size:
        a = buf[key] = np.empty(size, dtype=np.float32)
    return a[:size]
