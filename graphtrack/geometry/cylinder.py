"""Projection of a cylinder's two limb (silhouette) lines, vectorised over poses.

Chaumette's closed form, written with the tangent planes through the optical
centre. A cylinder in the camera frame has a point p0 on its axis, unit
direction d and radius r (metres). Let

    m = p0 - (p0 . d) d          the axis point nearest the optical centre
    u = m / |m|,  v = d x u      (|m| > r: the camera is outside the cylinder)

A plane through the optical centre with unit normal n is tangent to the
cylinder iff n . d = 0 and |n . p0| = r, which gives the two limb planes

    n_i = (r/|m|) u + s_i sqrt(1 - r^2/|m|^2) v,   s_1 = +1, s_2 = -1.

On the unit camera (x = X/Z, y = Y/Z) limb i is the line a x + b y + c = 0 with
(a, b, c) = n_i. With intrinsics K it becomes, in undistorted pixels,

    A = a/fx,  B = b/fy,  C = c - a cx/fx - b cy/fy,
    cos(theta) x + sin(theta) y = rho,  (cos theta, sin theta, -rho) = (A, B, C)/|(A, B)|

brought to the canonical theta in [0, pi) of :mod:`graphtrack.geometry.lines`.
Limb i touches the cylinder along its contour generator p0 - r n_i + t d.

Degenerate geometry is flagged per pose (``valid`` False), never returned as a
silent NaN (the returned numbers are then finite but meaningless):
camera inside or on the cylinder (|m| <= r), the reference point p0 behind
the camera (p0_z <= 0), and the shaft seen end-on (the line at infinity:
|(A, B)| ~ 0, or the axis within ``end_on_deg`` of the viewing ray).
"""
from __future__ import annotations

import numpy as np

from graphtrack.geometry.lines import canonical


def limb_planes(p0: np.ndarray, d: np.ndarray, r) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (..., 2, 3) of the two limb planes and the inside flag (...,).

    p0, d: (..., 3) in the camera frame (d need not be unit); r: radius (m).
    """
    p0 = np.asarray(p0, float)
    d = np.asarray(d, float)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    r = np.asarray(r, float)
    m = p0 - np.sum(p0 * d, -1, keepdims=True) * d
    mn = np.linalg.norm(m, axis=-1)
    inside = mn <= r * (1.0 + 1e-9)
    safe = np.where(inside, 1.0, mn)
    u = m / safe[..., None]
    v = np.cross(d, u)
    alpha = np.where(inside, 0.0, r / safe)
    beta = np.sqrt(np.clip(1.0 - alpha * alpha, 0.0, None))
    n1 = alpha[..., None] * u + beta[..., None] * v
    n2 = alpha[..., None] * u - beta[..., None] * v
    return np.stack([n1, n2], -2), inside


def project_cylinder(p0: np.ndarray, d: np.ndarray, r, K: np.ndarray,
                     end_on_deg: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Limb lines of a cylinder in undistorted pixels.

    Returns rho (..., 2) in px, theta (..., 2) in rad (canonical), and
    valid (...,) bool. Line 1 is the limb with s = +1 (on the d x u side).
    """
    p0 = np.asarray(p0, float)
    d = np.asarray(d, float)
    n, inside = limb_planes(p0, d, r)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    A = n[..., 0] / fx
    B = n[..., 1] / fy
    C = n[..., 2] - n[..., 0] * cx / fx - n[..., 1] * cy / fy
    s = np.hypot(A, B)
    at_infinity = np.any(s < 1e-12 * np.maximum(np.abs(C), 1e-300), axis=-1) | np.any(s == 0, axis=-1)
    ss = np.where(s == 0, 1.0, s)
    theta = np.arctan2(B / ss, A / ss)
    rho = -C / ss
    rho, theta = canonical(rho, theta)
    dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
    pn = p0 / np.maximum(np.linalg.norm(p0, axis=-1, keepdims=True), 1e-300)
    end_on = np.abs(np.sum(dn * pn, -1)) >= np.cos(np.radians(end_on_deg))
    behind = p0[..., 2] <= 0
    valid = ~(inside | at_infinity | end_on | behind)
    return rho, theta, valid


def contour_generators(p0: np.ndarray, d: np.ndarray, r) -> np.ndarray:
    """Points p0 - r n_i on the two contour generators (..., 2, 3); each
    generator is that point + t d."""
    n, _ = limb_planes(p0, d, r)
    return np.asarray(p0, float)[..., None, :] - np.asarray(r, float)[..., None, None] * n
