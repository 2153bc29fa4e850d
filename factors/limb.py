"""The shaft's limb lines as a function of E, with analytic derivatives.

Data (fixed per frame): the shaft axis in the BASE frame for that frame's joint
readings, point p0, unit direction d, radius r (m); the intrinsics K.
Variable: E = (R, t), camera-from-base, perturbed as E . Exp(xi), xi = (omega, v):

    p = R p0 + t,   dp/dxi = [-R [p0]x,  R]
    c = R d,        dc/dxi = [-R [d]x,   0]

The limb-plane normal n_i (:func:`graphtrack.geometry.cylinder.limb_planes`) is
the unit vector with n.c = 0 and n.p = r, so by implicit differentiation of
F(n) = (n.c, n.p - r, (n.n - 1)/2) = 0

    G dn = -(n^T dc, n^T dp, 0),      G = [c^T; p^T; n^T]

(G is singular only when the camera is on the cylinder, flagged invalid). The
pixel line is L = (A, B, C) = M n with M = [[1/fx, 0, 0], [0, 1/fy, 0],
[-cx/fx, -cy/fy, 1]] (cylinder.py), i.e. A x + B y + C = 0, and

    R(p | theta, rho) = cos(theta) x + sin(theta) y - rho = +-(A x + B y + C)/|(A, B)|.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment


def skew3(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def line_matrix(K: np.ndarray) -> np.ndarray:
    """M with (A, B, C) = M n (unit-camera line -> undistorted-pixel line)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return np.array([[1.0 / fx, 0.0, 0.0], [0.0, 1.0 / fy, 0.0], [-cx / fx, -cy / fy, 1.0]])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for (..., 3) arrays (cheaper than np.cross on tiny arrays)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


@dataclass(frozen=True)
class ShaftAxis:
    """Base-frame shaft axis of one frame's readings: p0, unit d (3,), radius r (m).
    Sp0 = -[p0]x and Sd = -[d]x are cached for the Jacobians."""

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
        return ShaftAxis(p0, d, float(r), -skew3(p0), -skew3(d))


def limb_lines(E: np.ndarray, axis: ShaftAxis, M: np.ndarray, jacobian: bool = True,
               end_on_deg: float = 2.0):
    """Pixel lines L (2, 3) of both limbs for the 4x4 E, their derivatives
    dL/dxi (2, 3, 6) (None without ``jacobian``) and ``valid`` (same flags as
    :func:`graphtrack.geometry.cylinder.project_cylinder`: camera inside the
    cylinder, p0 behind the camera, shaft end-on, line at infinity).

    Same normals as :func:`graphtrack.geometry.cylinder.limb_planes` (limb 0:
    s = +1), written out for one pose because this runs in every factor callback.
    """
    R, t = E[:3, :3], E[:3, 3]
    p = R @ axis.p0 + t
    c = R @ axis.d
    pc = float(p @ c)
    m = p - pc * c
    mn = float(np.sqrt(m @ m))
    pn = float(np.sqrt(p @ p))
    r = axis.r
    if mn <= r * (1.0 + 1e-9) or p[2] <= 0 or pn == 0 or abs(pc) / pn >= np.cos(np.radians(end_on_deg)):
        return np.zeros((2, 3)), None, False
    u = m / mn
    v = _cross(c, u)
    alpha = r / mn
    beta = np.sqrt(max(1.0 - alpha * alpha, 0.0))
    n = np.stack([alpha * u + beta * v, alpha * u - beta * v])   # (2, 3)
    L = n @ M.T
    s = np.hypot(L[:, 0], L[:, 1])
    if np.any(s < 1e-12 * np.maximum(np.abs(L[:, 2]), 1e-300)):
        return L, None, False
    if not jacobian:
        return L, None, True
    dp = np.hstack([R @ axis.Sp0, R])                          # (3, 6)
    dc = np.hstack([R @ axis.Sd, np.zeros((3, 3))])            # (3, 6)
    # G_i = [c; p; n_i]: G^-1 columns are (p x n, n x c, c x p) / det, det = c . (p x n)
    pxn = _cross(p, n)                                         # (2, 3)
    nxc = _cross(n, c)                                         # (2, 3)
    det = pxn @ c                                              # (2,)
    ndc = n @ dc                                               # (2, 6)
    ndp = n @ dp                                               # (2, 6)
    dn = -(pxn[:, :, None] * ndc[:, None, :] + nxc[:, :, None] * ndp[:, None, :]) / det[:, None, None]
    dL = np.einsum("ij,kjl->kil", M, dn)                       # (2, 3, 6)
    return L, dL, True


class LimbPairing:
    """What one frame's shaft factors (one E, one shaft axis) decide together:
    the limb lines of E, computed once for all of them, and the limb of each
    member: the pixel sets of :mod:`factors.shaft_pixels` or the detected
    lines of :mod:`factors.line_parameter`, each with ``costs(L)`` -> (2,),
    its cost against either limb of L (2, 3).

    ``limbs(E, L)`` gives the limb (0 / 1) of every member: the injective
    assignment of members to the two limbs with the least total cost (with
    more than two members, the two best-placed take the limbs injectively and
    the others their nearer limb; a lone member, in a pairing of its own, its
    nearer limb). Two detected shaft edges are two different
    limbs; left to choose alone, both take the nearer one whenever E is off
    by more than half the shaft's image width. Both are cached for the last E,
    so the frame's factors, evaluated at the same E, decide together once."""

    def __init__(self):
        self.members: list = []
        self._key = None
        self._limbs: list[int] = []
        self._lines_key = None
        self._lines = None

    def add(self, member) -> int:
        self.members.append(member)
        return len(self.members) - 1

    def lines(self, E: np.ndarray, axis: ShaftAxis, M: np.ndarray, jacobian: bool = True):
        """:func:`limb_lines` of E, shared by the members (which all carry the frame's axis and M)."""
        key = E.tobytes()
        if key != self._lines_key or (jacobian and self._lines[1] is None and self._lines[2]):
            self._lines_key, self._lines = key, limb_lines(E, axis, M, jacobian)
        return self._lines

    def limbs(self, E: np.ndarray, L: np.ndarray) -> list[int]:
        key = E.tobytes()
        if key != self._key:
            C = [m.costs(L) for m in self.members]                   # k x (2,)
            if len(C) == 2:  # the usual two edges: the cheaper of the two pairings
                limbs = [0, 1] if C[0][0] + C[1][1] <= C[0][1] + C[1][0] else [1, 0]
            else:
                limbs = [int(np.argmin(c)) for c in C]
                if len(C) > 2:
                    rows, cols = linear_sum_assignment(np.array(C))
                    for r, c in zip(rows, cols):
                        limbs[r] = int(c)
            self._key, self._limbs = key, limbs
        return self._limbs
