"""Image lines in polar form, the one convention used everywhere.

A line is (rho, theta) with

    cos(theta) * x + sin(theta) * y = rho

in UNDISTORTED pixel coordinates (x right, y down, origin at the top-left
pixel centre, as OpenCV). Canonical form: theta in [0, pi), rho signed (px),
which is OpenCV's HoughLines convention. (rho, theta) and (-rho, theta + pi)
are the same line; :func:`line_difference` compares two lines in whichever of
the two representations makes the angle difference smallest.

The pixel residual of the method is R(x, y | theta, rho) = cos(theta) x +
sin(theta) y - rho: the signed distance (px) of pixel (x, y) from the line.
"""
from __future__ import annotations

import numpy as np


def canonical(rho: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bring (rho, theta) to theta in [0, pi) (flipping the sign of rho)."""
    rho = np.asarray(rho, dtype=float)
    theta = np.asarray(theta, dtype=float)
    k = np.floor(theta / np.pi)
    theta_c = theta - k * np.pi
    rho_c = np.where(np.mod(k, 2) == 1, -rho, rho)
    # guard theta_c == pi from rounding
    wrap = theta_c >= np.pi
    return np.where(wrap, -rho_c, rho_c), np.where(wrap, theta_c - np.pi, theta_c)


def line_difference(rho_a, theta_a, rho_b, theta_b) -> tuple[np.ndarray, np.ndarray]:
    """(d_rho, d_theta) = line a - line b, with theta wrapped to [-pi/2, pi/2).

    Broadcasts. When the wrapped angle difference crosses pi/2 the second line
    is taken in its (-rho, theta +- pi) form so that d_rho compares like with like.
    """
    rho_a = np.asarray(rho_a, float)
    rho_b = np.asarray(rho_b, float)
    dth = np.asarray(theta_a, float) - np.asarray(theta_b, float)
    k = np.round(dth / np.pi)  # number of half-turns between the representations
    dth = dth - k * np.pi
    flip = np.mod(k, 2) == 1
    drho = np.where(flip, rho_a + rho_b, rho_a - rho_b)
    return drho, dth


def pixel_residual(points: np.ndarray, rho: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """R(x, y | theta, rho) = cos(theta) x + sin(theta) y - rho (px).

    points: (..., P, 2); rho, theta broadcast against the leading axes (...),
    returns (..., P).
    """
    p = np.asarray(points, float)
    c = np.cos(np.asarray(theta, float))[..., None]
    s = np.sin(np.asarray(theta, float))[..., None]
    return c * p[..., 0] + s * p[..., 1] - np.asarray(rho, float)[..., None]


def line_through(p1: np.ndarray, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical (rho px, theta rad) of the line through points p1, p2 (..., 2) px."""
    p1 = np.asarray(p1, float)
    p2 = np.asarray(p2, float)
    d = p2 - p1
    theta = np.arctan2(d[..., 0], -d[..., 1])  # normal = (-dy, dx) rotated: (cos, sin) _|_ d
    rho = np.cos(theta) * p1[..., 0] + np.sin(theta) * p1[..., 1]
    return canonical(rho, theta)


def point_segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance (px) of points (P, 2) to the segment a-b (each (2,)) -> (P,)."""
    p = np.asarray(points, float)
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    ab = b - a
    L2 = float(ab @ ab)
    t = np.zeros(len(p)) if L2 == 0 else np.clip((p - a) @ ab / L2, 0.0, 1.0)
    proj = a + t[:, None] * ab
    return np.linalg.norm(p - proj, axis=1)


def line_in_image(rho: float, theta: float, width: int, height: int, margin: float = 0.0) -> np.ndarray | None:
    """The two ends (2, 2) of cos(t) x + sin(t) y = rho clipped to the image rectangle (or None)."""
    c, s = np.cos(theta), np.sin(theta)
    x0, y0, x1, y1 = -margin, -margin, width - 1 + margin, height - 1 + margin
    cand = []
    if abs(s) > 1e-12:
        for x in (x0, x1):
            y = (rho - c * x) / s
            if y0 - 1e-9 <= y <= y1 + 1e-9:
                cand.append((x, y))
    if abs(c) > 1e-12:
        for y in (y0, y1):
            x = (rho - s * y) / c
            if x0 - 1e-9 <= x <= x1 + 1e-9:
                cand.append((x, y))
    if len(cand) < 2:
        return None
    cand = np.array(cand)
    d = np.linalg.norm(cand[:, None] - cand[None], axis=-1)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    return cand[[i, j]]
