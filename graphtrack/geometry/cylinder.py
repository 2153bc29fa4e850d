"""The shaft's projected limbs (silhouette lines) and the residuals against them.

Chaumette's closed form, written with the tangent planes through the optical
centre. A cylinder in the camera frame has a point p0 on its axis, unit
direction d and radius r (metres). Let

    m = p0 - (p0 . d) d          the axis point nearest the optical centre
    u = m / |m|,  v = d x u      (|m| > r: the camera is outside the cylinder)

A plane through the optical centre with unit normal n is tangent to the
cylinder iff n . d = 0 and |n . p0| = r, which gives the two limb planes

    n_i = (r/|m|) u + s_i sqrt(1 - r^2/|m|^2) v,   s_0 = +1, s_1 = -1.

On the unit camera (x = X/Z, y = Y/Z) limb i is the line a x + b y + c = 0 with
(a, b, c) = n_i. With intrinsics K it becomes, in undistorted pixels, the line
A x + B y + C = 0 with

    L = (A, B, C) = M n,   M = [[1/fx, 0, 0], [0, 1/fy, 0], [-cx/fx, -cy/fy, 1]]

(:func:`line_matrix`), and in the polar form of :mod:`graphtrack.geometry.lines`

    cos(theta) x + sin(theta) y = rho,   (cos theta, sin theta, -rho) = (A, B, C)/|(A, B)|.

Both normals point from the limb into the shaft's image. Limb i touches the
cylinder along its contour generator p0 - r n_i + t d.

Degenerate geometry is flagged per pose (``valid`` False), never returned as a
silent NaN (the numbers returned are then finite but meaningless): the camera
inside or on the cylinder (|m| <= r), the reference point p0 behind the
camera (p0_z <= 0), the shaft seen end-on (the axis within ``END_ON_DEG`` of
the viewing ray of p0) and a limb at infinity (|(A, B)| ~ 0).

Three forms of the projection, the same numbers to rounding:

- :func:`project_cylinder`: the reference, poses on any leading axes (..., 3),
  canonical (rho, theta) with theta in [0, pi);
- :func:`project_cylinder_batch`: N poses component-major ((3, N) in, (2, N)
  out: each numpy call runs over N contiguous numbers), the lines as rho and
  their unit normals (cos theta, sin theta), for the particle filter;
- :func:`limb_line_coefficients`: one pose E of a base-frame :class:`ShaftAxis`,
  the lines L = (A, B, C) and their derivatives in E's right perturbation,
  for the factors.

Residuals against a limb L (px): the pixel residual (signed distance)
:func:`pixel_residuals` and the line parameters (rho, theta) :func:`line_polar`,
each with its Jacobian in L.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.geometry.lines import canonical
from graphtrack.geometry.se3 import skew

#: the shaft counts as seen end-on (no limb lines) within this angle (deg) of the viewing ray
END_ON_DEG = 2.0
COS_END_ON = float(np.cos(np.radians(END_ON_DEG)))
#: relative margin of |m| over r under which the camera counts as inside the cylinder
INSIDE_MARGIN = 1e-9
#: a limb is at infinity when |(A, B)| < AT_INFINITY |C|
AT_INFINITY = 1e-12


def line_matrix(K: np.ndarray) -> np.ndarray:
    """M (3, 3) with L = (A, B, C) = M n: unit-camera line n -> undistorted-pixel line, for
    intrinsics K (px)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return np.array([[1.0 / fx, 0.0, 0.0], [0.0, 1.0 / fy, 0.0], [-cx / fx, -cy / fy, 1.0]])


# --- the reference ---------------------------------------------------------------------------

def limb_planes(p0: np.ndarray, d: np.ndarray, r) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals n_i (..., 2, 3) of the two limb planes and the inside flag (...,).

    p0, d: (..., 3) in the camera frame (m; d need not be unit); r: radius (m).
    """
    p0 = np.asarray(p0, float)
    d = np.asarray(d, float)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    r = np.asarray(r, float)
    m = p0 - np.sum(p0 * d, -1, keepdims=True) * d
    mn = np.linalg.norm(m, axis=-1)
    inside = mn <= r * (1.0 + INSIDE_MARGIN)
    safe = np.where(inside, 1.0, mn)
    u = m / safe[..., None]
    v = np.cross(d, u)
    alpha = np.where(inside, 0.0, r / safe)
    beta = np.sqrt(np.clip(1.0 - alpha * alpha, 0.0, None))
    n1 = alpha[..., None] * u + beta[..., None] * v
    n2 = alpha[..., None] * u - beta[..., None] * v
    return np.stack([n1, n2], -2), inside


def project_cylinder(p0: np.ndarray, d: np.ndarray, r, K: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Limb lines of a cylinder (p0, d: (..., 3) camera frame, m; r m) in undistorted pixels.

    Returns rho (..., 2) px, theta (..., 2) rad (canonical, [0, pi)) and
    valid (...,) bool (module doc). Line 0 is the limb with s = +1 (on the
    d x u side).
    """
    p0 = np.asarray(p0, float)
    d = np.asarray(d, float)
    n, inside = limb_planes(p0, d, r)
    L = n @ line_matrix(K).T
    A, B, C = L[..., 0], L[..., 1], L[..., 2]
    s = np.hypot(A, B)
    at_infinity = np.any(s < AT_INFINITY * np.maximum(np.abs(C), 1e-300), axis=-1) | np.any(s == 0, axis=-1)
    ss = np.where(s == 0, 1.0, s)
    rho, theta = canonical(-C / ss, np.arctan2(B / ss, A / ss))
    dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
    pn = p0 / np.maximum(np.linalg.norm(p0, axis=-1, keepdims=True), 1e-300)
    end_on = np.abs(np.sum(dn * pn, -1)) >= COS_END_ON
    behind = p0[..., 2] <= 0
    valid = ~(inside | at_infinity | end_on | behind)
    return rho, theta, valid


def contour_generators(p0: np.ndarray, d: np.ndarray, r) -> np.ndarray:
    """Points p0 - r n_i on the two contour generators (..., 2, 3) (m); each
    generator is that point + t d."""
    n, _ = limb_planes(p0, d, r)
    return np.asarray(p0, float)[..., None, :] - np.asarray(r, float)[..., None, None] * n


# --- batched over N poses (the particle filter) ----------------------------------------------

def project_cylinder_batch(p0: np.ndarray, d: np.ndarray, r: float, K: np.ndarray, sides: bool = False):
    """:func:`project_cylinder` for N poses, component-major: p0 (3, N) axis points and
    UNIT directions d (3, N) (camera frame, m), one radius r (m).

    Same lines, line order and ``valid`` flag, each line returned as rho and its
    canonical unit normal (cos theta, sin theta) (sin theta >= 0, theta in
    [0, pi)), so that the pixel models need no trigonometry (theta:
    :func:`line_angles`). Returns rho, cos, sin (2, N) (px, -, -) and valid (N,);
    with ``sides`` also inward (2, N): +-1, the sign of cos x + sin y - rho on the
    shaft's side of each line. A limb plane's normal n = alpha u +- beta v has
    n . X = alpha |m| = r > 0 at every point X of the axis, so the image of the axis in
    front of the camera lies where (A, B, C) . (x, y, 1) > 0: inward is the sign of the
    canonical scale k (exact under perspective, converging limbs included).
    """
    px, py, pz = p0
    dx, dy, dz = d
    pd = px * dx + py * dy + pz * dz
    mx, my, mz = px - pd * dx, py - pd * dy, pz - pd * dz
    mn = np.sqrt(mx * mx + my * my + mz * mz)
    inside = mn <= r * (1.0 + INSIDE_MARGIN)
    inv = 1.0 / np.where(inside, 1.0, mn)
    ux, uy, uz = mx * inv, my * inv, mz * inv
    alpha = np.where(inside, 0.0, r * inv)
    beta = np.sqrt(np.clip(1.0 - alpha * alpha, 0.0, None))
    # limb normals n = alpha u +- beta v, v = d x u; row 0 takes +, row 1 takes -
    pm = np.array([[1.0], [-1.0]])
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    A = (alpha * ux + pm * (beta * (dy * uz - dz * uy))) * (1.0 / fx)  # (2, N)
    B = (alpha * uy + pm * (beta * (dz * ux - dx * uz))) * (1.0 / fy)
    C = alpha * uz + pm * (beta * (dx * uy - dy * ux)) - A * cx - B * cy
    s2 = A * A + B * B
    at_inf = s2 <= (AT_INFINITY * AT_INFINITY) * C * C
    # canonical: sin theta >= 0 (theta in [0, pi)), i.e. flip (A, B, C) when B < 0 or B = 0 > A
    k = np.where((B < 0) | ((B == 0) & (A < 0)), -1.0, 1.0) / np.sqrt(np.where(s2 > 0, s2, 1.0))
    pn = np.sqrt(px * px + py * py + pz * pz)
    end_on = np.abs(pd) >= COS_END_ON * np.maximum(pn, 1e-300)
    valid = ~(inside | at_inf[0] | at_inf[1] | end_on | (pz <= 0))
    if sides:
        return -C * k, A * k, B * k, valid, np.sign(k)
    return -C * k, A * k, B * k, valid


def line_angles(cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """theta (rad, in [0, pi)) of canonical unit normals (cos, sin) of :func:`project_cylinder_batch`."""
    return np.arctan2(sin, cos)


# --- one pose with Jacobians (the factors) ---------------------------------------------------

@dataclass(frozen=True)
class ShaftAxis:
    """A shaft in the BASE frame (one frame's joint readings): axis point p0 and unit
    direction d (3,) (m), radius r (m). Sp0 = -[p0]x and Sd = -[d]x are cached for
    the Jacobians of :func:`limb_line_coefficients`."""

    p0: np.ndarray
    d: np.ndarray
    r: float
    Sp0: np.ndarray
    Sd: np.ndarray

    @staticmethod
    def make(p0, d, r) -> "ShaftAxis":
        p0 = np.asarray(p0, float).copy()
        d = np.asarray(d, float)
        d = d / np.linalg.norm(d)
        return ShaftAxis(p0, d, float(r), -skew(p0), -skew(d))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for (..., 3) arrays (cheaper than np.cross on tiny arrays)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


def limb_line_coefficients(E: np.ndarray, axis: ShaftAxis, M: np.ndarray, jacobian: bool = True):
    """Pixel lines L (2, 3) = (A, B, C) of both limbs for the 4x4 camera-from-base E, their
    derivatives dL/dxi (2, 3, 6) (None without ``jacobian`` or when not valid) and
    ``valid`` (bool, the flags of :func:`project_cylinder`); M = :func:`line_matrix` (K).

    L_i = M n_i with the normals of :func:`limb_planes` (limb 0: s = +1), not
    normalised. E is perturbed on the right, E . Exp(xi), xi = (omega, v)
    (rotation first, as gtsam), so with p = R p0 + t and c = R d

        dp/dxi = [-R [p0]x, R],   dc/dxi = [-R [d]x, 0].

    n is the unit vector with n.c = 0 and n.p = r; differentiating
    F(n) = (n.c, n.p - r, (n.n - 1)/2) = 0 implicitly gives

        G dn = -(n^T dc, n^T dp, 0),   G = [c^T; p^T; n^T],

    whose inverse has the columns (p x n, n x c, c x p) / det, det = c.(p x n)
    (G is singular only with the camera on the cylinder, flagged invalid);
    dL = M dn.
    """
    R, t = E[:3, :3], E[:3, 3]
    p = R @ axis.p0 + t
    c = R @ axis.d
    pc = float(p @ c)
    m = p - pc * c
    mn = float(np.sqrt(m @ m))
    pn = float(np.sqrt(p @ p))
    r = axis.r
    if mn <= r * (1.0 + INSIDE_MARGIN) or p[2] <= 0 or pn == 0 or abs(pc) / pn >= COS_END_ON:
        return np.zeros((2, 3)), None, False
    u = m / mn
    v = _cross(c, u)
    alpha = r / mn
    beta = np.sqrt(max(1.0 - alpha * alpha, 0.0))
    n = np.stack([alpha * u + beta * v, alpha * u - beta * v])   # (2, 3)
    L = n @ M.T
    s = np.hypot(L[:, 0], L[:, 1])
    if np.any(s < AT_INFINITY * np.maximum(np.abs(L[:, 2]), 1e-300)):
        return L, None, False
    if not jacobian:
        return L, None, True
    dp = np.hstack([R @ axis.Sp0, R])                          # (3, 6)
    dc = np.hstack([R @ axis.Sd, np.zeros((3, 3))])            # (3, 6)
    pxn = _cross(p, n)                                         # (2, 3)
    nxc = _cross(n, c)                                         # (2, 3)
    det = pxn @ c                                              # (2,)
    ndc = n @ dc                                               # (2, 6)
    ndp = n @ dp                                               # (2, 6)
    dn = -(pxn[:, :, None] * ndc[:, None, :] + nxc[:, :, None] * ndp[:, None, :]) / det[:, None, None]
    dL = np.einsum("ij,kjl->kil", M, dn)                       # (2, 3, 6)
    return L, dL, True


# --- residuals against a line L = (A, B, C) --------------------------------------------------

def pixel_residuals(h: np.ndarray, L: np.ndarray) -> np.ndarray:
    """The pixel residual R(p | theta, rho) = cos(theta) x + sin(theta) y - rho
    = (A x + B y + C)/|(A, B)| (px, signed distance; positive on the side (A, B)
    points to) of homogeneous pixels h (m, 3) = (x, y, 1) against lines L (k, 3)
    -> (m, k). Polar lines (:func:`graphtrack.geometry.lines.pixel_residual`) are
    L = (cos theta, sin theta, -rho)."""
    return (h @ L.T) / np.hypot(L[:, 0], L[:, 1])


def pixel_residual_jacobian(h: np.ndarray, L: np.ndarray, dL: np.ndarray,
                            residual: np.ndarray) -> np.ndarray:
    """dR/dxi (m, q) of :func:`pixel_residuals` against ONE line L (3,) with dL/dxi (3, q),
    given the residuals (m,) px:

        dR/dxi = (h - R (A, B, 0)/s) / s . dL/dxi,   s = |(A, B)|.
    """
    s = np.hypot(L[0], L[1])
    dLs = dL / s
    ab0 = np.array([L[0], L[1], 0.0]) / s
    return h @ dLs - residual[:, None] * (ab0 @ dLs)[None, :]


def line_polar(L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho, theta) (px, rad) of lines L (..., 3) = (A, B, C), NOT canonicalised:
    theta = atan2(B, A), rho = -C/|(A, B)| (continuous in L; compare with
    :func:`graphtrack.geometry.lines.line_difference`)."""
    A, B, C = L[..., 0], L[..., 1], L[..., 2]
    return -C / np.hypot(A, B), np.arctan2(B, A)


def line_polar_jacobian(L: np.ndarray) -> np.ndarray:
    """d(rho, theta)/dL (2, 3) of :func:`line_polar` for one line L (3,):

        d rho/dL = (C A/s^3, C B/s^3, -1/s),   d theta/dL = (-B, A, 0)/s^2,   s = |(A, B)|.
    """
    a, b, c = L
    s = np.hypot(a, b)
    return np.array([[c * a / s ** 3, c * b / s ** 3, -1.0 / s],
                     [-b / s ** 2, a / s ** 2, 0.0]])
