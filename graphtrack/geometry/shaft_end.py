"""The point at which the shaft visibly ends along its projected axis.

The shaft is a cylinder of radius r about an axis with unit direction a, whose
distal end (where the dark shaft meets the wrist) is the circle of centre c
(camera frame, metres, the camera centre at the origin). The image of the axis
is the image of the plane through the camera centre and the axis; on the shaft's
surface that plane holds two generators, and the one nearer the camera,
c + r u + lambda a, is the one seen along the middle of the shaft's image, with

    w = -c + (c . a) a,     u = w / |w|

(u: the direction to the camera, -c, made orthogonal to a). So along the
projected axis the shaft ends at the image of the front point of its end rim,

    P = c + r u,

not at the image of c: r u moves it along the axis's image by up to r f / Z
(about 25 px for a 4 mm shaft 10 cm away under a 620 px focal length, seen
obliquely). The detector (:mod:`graphtrack.detect.shaft_end`) finds the
dark-to-bright step on the middle of the shaft's image; the estimators predict it
as the projection of P.

Derivatives (for the factor's Jacobian, :mod:`factors.shaft_end`):

    dw = -dc + ((dc . a) + (c . da)) a + (c . a) da
    du = (I - u u^T) dw / |w|
    dP = dc + r du
"""
from __future__ import annotations

import numpy as np


def front_point(c: np.ndarray, a: np.ndarray, r: float) -> np.ndarray:
    """P = c + r u (module doc) for end centres c and unit axis directions a
    (..., 3), metres, camera frame. Where the camera looks straight along the axis
    (|w| = 0) P is c."""
    c = np.asarray(c, float)
    a = np.asarray(a, float)
    w = -c + np.sum(c * a, axis=-1, keepdims=True) * a
    n = np.linalg.norm(w, axis=-1, keepdims=True)
    return c + r * w / np.where(n > 1e-12, n, np.inf)


def front_point_jacobian(c: np.ndarray, a: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P (3,) and dP/dc, dP/da (3, 3) at one end centre c and unit direction a
    (module doc; a is treated as a free 3-vector, the caller keeps it unit)."""
    c = np.asarray(c, float)
    a = np.asarray(a, float)
    ca = float(c @ a)
    w = -c + ca * a
    n = float(np.linalg.norm(w))
    if n <= 1e-12:
        return c.copy(), np.eye(3), np.zeros((3, 3))
    u = w / n
    proj = (np.eye(3) - np.outer(u, u)) / n
    dw_dc = -np.eye(3) + np.outer(a, a)
    dw_da = np.outer(a, c) + ca * np.eye(3)
    return c + r * u, np.eye(3) + r * proj @ dw_dc, r * proj @ dw_da


def end_pixel(c: np.ndarray, a: np.ndarray, r: float, K: np.ndarray):
    """(pixel (2,), direction (2,)): the image of P (module doc) under the pinhole K and
    the unit image direction along the shaft towards it (from the image of c - 1 cm a);
    None when either point is behind the camera or the direction is degenerate."""
    a = np.asarray(a, float)
    pts = np.stack([np.asarray(c, float) - 0.01 * a, front_point(c, a, r)]) @ np.asarray(K, float).T
    if not np.all(pts[:, 2] > 1e-6):
        return None
    uv = pts[:, :2] / pts[:, 2:]
    d = uv[1] - uv[0]
    n = np.linalg.norm(d)
    return (uv[1], d / n) if n > 1e-9 else None
