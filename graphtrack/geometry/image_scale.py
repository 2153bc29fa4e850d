"""Pixel coordinates under an image resize by factors (s_x, s_y), pixel centres mapped
as OpenCV's resize maps them (the centre of pixel 0 at x = 0):

    x' = (x + 0.5) s_x - 0.5,   y' = (y + 0.5) s_y - 0.5                         (points)

A polar line cos(t) x + sin(t) y = rho under a uniform resize s keeps its angle t:

    rho' = s (rho + c / 2) - c / 2,   c = cos t + sin t                           (lines)

The inverse resize is the same map with 1 / s. :meth:`graphtrack.geometry.camera.Camera.scaled`
moves the principal point by the points' map.
"""
from __future__ import annotations

import numpy as np


def scale_points(p, sx: float, sy: float | None = None) -> np.ndarray:
    """Points (..., 2) or segments (..., 4) as (x, y) pairs, px -> px of the resized image
    (a new array; sy defaults to sx)."""
    q = np.array(p, float)
    q[..., 0::2] = (q[..., 0::2] + 0.5) * sx - 0.5
    q[..., 1::2] = (q[..., 1::2] + 0.5) * (sx if sy is None else sy) - 0.5
    return q


def scale_lines(lines, s: float) -> np.ndarray:
    """Polar lines (N, 2) (rho px, theta rad) -> the resized image's (a new array)."""
    lines = np.array(lines, float).reshape(-1, 2)
    if len(lines):
        c = np.cos(lines[:, 1]) + np.sin(lines[:, 1])
        lines[:, 0] = s * (lines[:, 0] + c / 2) - c / 2
    return lines
