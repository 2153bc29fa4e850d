"""Sub-pixel refit of Hough lines from their oriented edge pixels, and each line's segment.

A line (rho, theta) has normal n = (cos theta, sin theta) and direction
(-sin theta, cos theta); a pixel p's residual is R(p) = p . n - rho (px). A
line only looks at the edge pixels whose gradient angle phi (mod pi) is within
``orientation_tol`` rad of its theta (None: all of them). With ``refine``:

1. fine local Hough: the voters (|R| <= rho_res/2 + 1/2) give a pivot q
   (their centroid); the lines through q + o n(theta + delta), delta in
   +-fine_theta (step 0.01 rad), o in +-rho_res (1 px bins, summed in pairs)
   are voted on by the window's pixels; the best one wins;
2. total least squares on the pixels with |R| <= 2 band, then <= band
   (band = max(refine_band, 1/s) px, s the detector's downscale).

Segment: the final inlier pixels projected on the line direction, split at
gaps > ``max_gap`` px; the longest run gives the endpoints. Units:
full-resolution undistorted px and rad. Decisions and measurements:
docs/decisions/canny-detector-changes.md.
"""
from __future__ import annotations

import numpy as np

from graphtrack.detect.ransac import tls_from_moments
from graphtrack.geometry.lines import canonical


def orientation_windows(theta: np.ndarray, ph: np.ndarray, tol: float | None):
    """(line id, index into ph) of the sorted-phi pixels within tol of each theta.

    phi is sorted once and each window is a slice (two at the wrap-around), so
    the work is sum_j |window_j| rather than P x N."""
    P = len(ph)
    los, his, ids = [], [], []
    for j, t in enumerate(theta):
        if tol is None or tol >= 0.5 * np.pi:
            parts = [(0.0, np.pi)]
        else:
            lo, hi = t - tol, t + tol
            parts = [(max(lo, 0.0), min(hi, np.pi))]
            if lo < 0:
                parts.append((lo + np.pi, np.pi))
            if hi > np.pi:
                parts.append((0.0, hi - np.pi))
        for lo, hi in parts:
            los.append(lo)
            his.append(hi)
            ids.append(j)
    a = np.searchsorted(ph, los, side="left")
    b = np.searchsorted(ph, his, side="right") if P else a
    n = np.maximum(b - a, 0)
    total = int(n.sum())
    if total == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    lid = np.repeat(np.asarray(ids), n)
    off = np.repeat(a - np.concatenate([[0], np.cumsum(n)[:-1]]), n)
    return lid, np.arange(total) + off


def _pivots(rho, theta, x, y, lid, ctr, rho_res: float):
    """Step 1's pivots (centred px): the voters' centroid, else the foot of the line."""
    N = len(rho)
    c, sn = np.cos(theta), np.sin(theta)
    rc = rho - c * ctr[0] - sn * ctr[1]                  # lines in centred coordinates
    u = x * c[lid] + y * sn[lid] - rc[lid]                 # offset from the Hough line
    vote = np.abs(u) <= 0.5 * rho_res + 0.5
    cnt = np.bincount(lid[vote], minlength=N).astype(float)
    px = np.bincount(lid[vote], weights=x[vote], minlength=N) / np.maximum(cnt, 1)
    py = np.bincount(lid[vote], weights=y[vote], minlength=N) / np.maximum(cnt, 1)
    none = cnt == 0
    px[none], py[none] = (rc * c)[none], (rc * sn)[none]
    return px, py


def fine_hough(rho, theta, Xs, ph, ctr, *, orientation_tol: float | None, rho_res: float,
               fine_theta: float):
    """Step 1 of the module doc (Xs: pixels centred on ctr, sorted by phi); (rho, theta)."""
    N = len(rho)
    lid, idx = orientation_windows(theta, ph, orientation_tol)
    if len(idx) == 0:
        return rho, theta
    x, y = Xs[idx, 0], Xs[idx, 1]
    c, sn = np.cos(theta), np.sin(theta)
    px, py = _pivots(rho, theta, x, y, lid, ctr, rho_res)
    R = float(rho_res)
    dmax = float(fine_theta)
    deltas = np.arange(-dmax, dmax + 1e-9, 0.01)
    qx, qy = x - px[lid], y - py[lid]
    u = qx * c[lid] + qy * sn[lid]
    v = -qx * sn[lid] + qy * c[lid]
    keep = np.abs(u) <= R + 1.0 + np.abs(v) * np.sin(dmax)
    u, v, lj = u[keep], v[keep], lid[keep]
    if len(u) == 0:
        return rho, theta
    nb = int(2 * R) + 1
    T = len(deltas)
    # offset bin b = floor(o + R) in [0, nb); stored as b + 1 with the two
    # outer bins (b < 0, b >= nb) catching what falls outside
    o = (u.astype(np.float32)[:, None] * np.cos(deltas).astype(np.float32)
         + v.astype(np.float32)[:, None] * np.sin(deltas).astype(np.float32))
    o += np.float32(R + 1.0)
    np.clip(o, 0.0, nb + 1.0, out=o)
    b = o.astype(np.int32)
    b += ((lj.astype(np.int32) * T)[:, None] + np.arange(T, dtype=np.int32)) * (nb + 2)
    acc = np.bincount(b.ravel(), minlength=N * T * (nb + 2)).reshape(N, T, nb + 2)[:, :, 1:-1]
    acc2 = acc[:, :, :-1] + acc[:, :, 1:]                  # 2-px windows, centre at bin edge
    best = acc2.reshape(N, -1).argmax(1)
    k, bo = np.divmod(best, nb - 1)
    has = acc2.reshape(N, -1).max(1) > 0
    th = theta + deltas[k]
    off = bo + 1.0 - R                                      # window centre offset (px)
    cn, snn = np.cos(th), np.sin(th)
    r_new = (px * cn + py * snn + off) + cn * ctr[0] + snn * ctr[1]
    r_new, th = canonical(r_new, th)
    return np.where(has, r_new, rho), np.where(has, th, theta)


def longest_runs(rho, theta, x, y, lid, ctr, max_gap: float):
    """Segments (N, 4) and support (N,) of the lines from their inliers (x, y centred
    on ctr, lid their line ids): per line, the longest run split at gaps > max_gap."""
    N = len(rho)
    segs = np.full((N, 4), np.nan)
    support = np.zeros(N, dtype=int)
    c, sn = np.cos(theta), np.sin(theta)
    t = (x + ctr[0]) * -sn[lid] + (y + ctr[1]) * c[lid]
    o = np.lexsort((t, lid))
    t, lid = t[o], lid[o]
    new_run = np.ones(len(t), dtype=bool)
    new_run[1:] = (np.diff(t) > max_gap) | (np.diff(lid) != 0)
    starts = np.flatnonzero(new_run)
    ends = np.append(starts[1:] - 1, len(t) - 1)
    extent = t[ends] - t[starts]
    run_line = lid[starts]
    # per line, the run with the largest extent (ties: first)
    ro = np.lexsort((-extent, run_line))
    first = np.ones(len(ro), dtype=bool)
    first[1:] = run_line[ro][1:] != run_line[ro][:-1]
    best = ro[first]
    j = run_line[best]
    t0, t1 = t[starts[best]], t[ends[best]]
    fx, fy = rho[j] * c[j], rho[j] * sn[j]
    segs[j] = np.stack([fx - t0 * sn[j], fy + t0 * c[j], fx - t1 * sn[j], fy + t1 * c[j]], 1)
    support[j] = ends[best] - starts[best] + 1
    segs[support < 2] = np.nan
    return segs, support


def refit_lines(lines: np.ndarray, X: np.ndarray, phi: np.ndarray, s: float, *,
                orientation_tol: float | None, refine: bool, refine_band: float, fine_theta: float,
                rho_res: float, max_gap: float):
    """Refits and candidate segments of Hough lines (N, 2) (module doc).

    X: (P, 2) full-resolution edge pixels, phi: (P,) their gradient angles mod
    pi, s: the detector's downscale. Returns lines (N, 2), segments (N, 4)
    (NaN rows when a line kept < 2 pixels) and support (N,) (pixels in the segment).
    """
    N = len(lines)
    rho, theta = lines[:, 0].copy(), lines[:, 1].copy()
    ctr = X.mean(0)
    order = np.argsort(phi, kind="stable")
    ph, Xs = phi[order], X[order] - ctr
    final = max(refine_band, 1.0 / s)
    if refine:
        rho, theta = fine_hough(rho, theta, Xs, ph, ctr, orientation_tol=orientation_tol,
                                rho_res=rho_res, fine_theta=fine_theta)
    bands = [2.0 * final, final] if refine else [final]
    lid = idx = None
    for band in bands:
        lid, idx = orientation_windows(theta, ph, orientation_tol)
        if len(idx) == 0:
            break
        x, y = Xs[idx, 0], Xs[idx, 1]
        c, sn = np.cos(theta), np.sin(theta)
        rc = rho - c * ctr[0] - sn * ctr[1]
        m = np.abs(x * c[lid] + y * sn[lid] - rc[lid]) <= band
        lid, idx, x, y = lid[m], idx[m], x[m], y[m]
        if not refine:
            break
        cnt = np.bincount(lid, minlength=N).astype(float)
        ok = cnt >= 2
        if not ok.any():
            continue
        mom = [np.bincount(lid, weights=v, minlength=N)[ok] for v in (x, y, x * x, x * y, y * y)]
        r2, t2 = tls_from_moments(cnt[ok], *mom)
        r2 = r2 + np.cos(t2) * ctr[0] + np.sin(t2) * ctr[1]
        rho[ok], theta[ok] = canonical(r2, t2)
    if idx is None or len(idx) == 0:
        return np.stack([rho, theta], 1), np.full((N, 4), np.nan), np.zeros(N, dtype=int)
    segs, support = longest_runs(rho, theta, x, y, lid, ctr, max_gap)
    return np.stack([rho, theta], 1), segs, support
