"""Hough lines of an edge map, with votes filtered by the edge pixels' gradient direction.

Coordinates: the edge map is the detector's downscaled image (scale s); the
returned lines (rho, theta) are full-resolution undistorted pixels, a
low-resolution pixel (u, v) standing for ((u + 1/2)/s - 1/2, (v + 1/2)/s - 1/2),
so rho = (rho_s - (s/2 - 1/2)(cos theta + sin theta)) / s. rho_res (px) and
votes are full-resolution; the transform runs with rho_res s px and votes s.

Oriented voting: theta in [0, pi) is cut into sectors of 5 bins of theta_res;
an edge pixel with gradient angle phi = atan2(g_y, g_x) mod pi votes only in
the sectors that come within ``orientation_tol`` rad of phi (a line's normal
is its pixels' gradient direction). Peaks are kept strongest first after
suppressing duplicates (:func:`suppress`). Decisions and measurements:
docs/decisions/canny-detector-changes.md.
"""
from __future__ import annotations

import cv2
import numpy as np

from graphtrack.geometry.image_scale import scale_lines
from graphtrack.geometry.lines import canonical, line_difference


def suppress(near: np.ndarray, limit: int) -> list[int]:
    """Greedy suppression over rows sorted strongest first; near: (N, N) bool.
    Returns the kept rows (at most ``limit``), each suppressing the rows near it."""
    suppressed = np.zeros(len(near), dtype=bool)
    keep: list[int] = []
    for i in range(len(near)):
        if suppressed[i]:
            continue
        keep.append(i)
        if len(keep) >= limit:
            break
        suppressed |= near[i]
    return keep


def _accumulate(edges, rres: float, tres: float, thr: int, xs, ys, phi, orientation_tol) -> list:
    """(rho_s, theta, votes) rows of each accumulator run: plain, or one per sector."""
    if phi is None or orientation_tol is None:
        out = cv2.HoughLinesWithAccumulator(edges, rres, tres, thr)
        return [] if out is None else [out.reshape(-1, 3)]
    found = []
    tol = float(orientation_tol)
    width = 5 * tres
    for k in range(int(np.ceil(np.pi / width))):
        lo, hi = k * width, min((k + 1) * width, np.pi)
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + tol
        d = np.abs(np.mod(phi - centre + 0.5 * np.pi, np.pi) - 0.5 * np.pi)
        m = d <= half
        if m.sum() < thr:
            continue
        img = np.zeros_like(edges)
        img[ys[m], xs[m]] = 255
        out = cv2.HoughLinesWithAccumulator(img, rres, tres, thr, min_theta=lo, max_theta=hi)
        if out is not None:
            found.append(out.reshape(-1, 3))
    return found


def hough_lines(edges: np.ndarray, s: float, shape, *, rho_res: float, theta_res: float, votes: int,
                orientation_tol: float | None, max_hough: int, max_lines: int,
                cluster: tuple[float, float] | None = None,
                xs=None, ys=None, phi=None) -> np.ndarray:
    """Hough lines (N, 2) full-resolution (rho, theta), strongest first (module doc).

    edges: the (downscaled) edge map; shape: the full-resolution (H, W); xs,
    ys, phi: the edge pixels and their gradient angles mod pi (oriented voting
    when phi and orientation_tol are given). The ``max_hough`` strongest peaks
    are suppressed to ``max_lines``: with ``cluster`` = (px, rad), of
    near-duplicates (rho measured from the image centre), else of exact
    duplicates only (a bin shared by two sectors).
    """
    thr = max(1, int(round(votes * s)))
    found = _accumulate(edges, rho_res * s, theta_res, thr, xs, ys, phi, orientation_tol)
    if not found:
        return np.zeros((0, 2))
    hl = np.concatenate(found).astype(float)
    hl = hl[np.argsort(-hl[:, 2], kind="stable")][:max_hough]
    rho = scale_lines(hl[:, :2], 1.0 / s)[:, 0]       # detected at scale s -> full-size px
    rho, theta = canonical(rho, hl[:, 1])
    if cluster is not None:
        H, W = shape
        rc = rho - (np.cos(theta) * (W - 1) / 2 + np.sin(theta) * (H - 1) / 2)
        drho, dth = line_difference(rc[:, None], theta[:, None], rc[None], theta[None])
        near = (np.abs(drho) <= cluster[0]) & (np.abs(dth) <= cluster[1] + 1e-9)
    else:
        near = (np.abs(rho[:, None] - rho[None]) < 1e-6) & (np.abs(theta[:, None] - theta[None]) < 1e-6)
    keep = suppress(near, max_lines)
    return np.stack([rho[keep], theta[keep]], 1)
