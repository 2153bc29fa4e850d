"""Projection of every particle's hypothesis of E at once: shaft limb lines and markers.

A particle x_n = (b_n, w_n) (m, rad) stands for E(x_n) = [R(w_n) b_n; 0 1] . E_0.
The frame's features are first mapped by the prior E_0 (once per frame, the
(3, K) matrix V of :func:`frame_geometry`), so that for particle n

    camera_X = R(w_n) (E_0 X) + b_n,

i.e. one (3N, 3) x (3, K) product for all particles and features. The shaft
(point p0 on the axis, unit direction d, radius r) then projects to its two
limb lines with Chaumette's closed form
(:func:`graphtrack.geometry.cylinder.project_cylinder_batch`),
the markers with the pinhole K (undistorted pixels).

Layout. Everything here is component-major ("structure of arrays"): a
rotation is (3, 3, N), a point (3, N), lines (2, N). Each numpy call then
runs over N contiguous numbers, which for N ~ 1000 is several times faster
than the (N, 3) layout, whose short inner axis defeats vectorisation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.geometry import pinhole
from graphtrack.geometry.cylinder import line_angles, project_cylinder_batch
from graphtrack.geometry.painted_marker import on_surface
from graphtrack.geometry.se3 import so3_exp_batch
from graphtrack.geometry.shaft_end import front_point
from graphtrack.robot.kinematics import link_transforms


@dataclass
class FrameGeometry:
    """The frame's features mapped by E_0 (metres, camera frame of the prior).

    V (3, 2 + 2M (+ 1)): columns [p0, d, markers_1..M, normals_1..M] (points and
    directions), then the centre of the shaft's distal end when robot.json gives it
    (``has_end``); r: shaft radius (m); on_shaft (M,): markers painted on the
    shaft (visible only on the side facing the camera; their normals are the
    outward radial directions, zero for the others); marker_links (M, 4, 4):
    base_T_link of the link each marker is painted on."""

    V: np.ndarray
    r: float
    on_shaft: np.ndarray
    has_end: bool = False
    marker_links: np.ndarray | None = None


def frame_geometry(robot, q: np.ndarray, E0: np.ndarray) -> FrameGeometry:
    """Shaft axis, markers and marker normals for joint reading q, mapped by E_0."""
    L = link_transforms(robot, q)
    sf = robot.shaft_features[0]
    Ts = L[sf.link]
    p0 = Ts[:3, :3] @ np.asarray(sf.position, float) + Ts[:3, 3]
    d = Ts[:3, :3] @ np.asarray(sf.direction, float)
    d = d / np.linalg.norm(d)
    r = float(sf.radius)
    feats = robot.point_features
    if feats:
        Tp = L[[p.link for p in feats]]
        pos = np.array([p.position for p in feats], float)
        pts = np.einsum("kij,kj->ki", Tp[:, :3, :3], pos) + Tp[:, :3, 3]
    else:
        Tp, pts = np.zeros((0, 4, 4)), np.zeros((0, 3))
    R0, t0 = E0[:3, :3], E0[:3, 3]
    rel = pts - p0
    radial = rel - (rel @ d)[:, None] * d
    dist = np.linalg.norm(radial, axis=1)
    # painted on the shaft: on its surface and on its link, as robot.features.marker_discs decides
    on_shaft = on_surface(pts, p0, d, r) & (np.array([p.link for p in feats], int) == sf.link)
    normals = np.where(on_shaft[:, None], radial / np.maximum(dist, 1e-12)[:, None], 0.0)
    cols = [(R0 @ p0 + t0)[:, None], (R0 @ d)[:, None], (pts @ R0.T + t0).T, (normals @ R0.T).T]
    if sf.end is not None:
        cols.append((R0 @ (p0 + sf.end * d) + t0)[:, None])
    return FrameGeometry(np.concatenate(cols, axis=1), r, on_shaft, sf.end is not None, Tp)


@dataclass
class Hypotheses:
    """Every particle's projection (component-major, N particles, M markers).

    rho, cos, sin (2, N): the shaft limb lines cos(theta) x + sin(theta) y = rho
    (px); valid (N,); u, v (M, N): marker pixels; visible (M, N): in front of
    the camera and, for markers on the shaft, on the side facing it;
    R (3, 3, N): R(w_n); end_u, end_v (N,): where the shaft visibly ends along its
    image, the projection of its end rim's front point
    (:func:`graphtrack.geometry.shaft_end.front_point`), None without a shaft end;
    inward (2, N): +-1, the side of each limb line the shaft's image lies on
    (:func:`graphtrack.geometry.cylinder.project_cylinder_batch`).
    ``theta`` (2, N) rad is computed when first read."""

    rho: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    valid: np.ndarray
    u: np.ndarray
    v: np.ndarray
    visible: np.ndarray
    R: np.ndarray
    end_u: np.ndarray | None = None
    end_v: np.ndarray | None = None
    inward: np.ndarray | None = None
    _theta: np.ndarray | None = None

    @property
    def theta(self) -> np.ndarray:
        if self._theta is None:
            self._theta = line_angles(self.cos, self.sin)
        return self._theta

    def limb_rho(self, width=0.0) -> np.ndarray:
        """rho (N, 2) of the limb lines moved ``width`` px (scalar or (N,)) towards the shaft's
        image, rho_i + inward_i width: a detector that finds both edges that far inside
        the limbs (> 0) or outside them (docs/decisions/pf-width-offset.md)."""
        return (self.rho + self.inward * width).T if np.any(width) else self.rho.T


def project(geometry: FrameGeometry, K: np.ndarray, x: np.ndarray, extrinsic: np.ndarray | None = None,
            R: np.ndarray | None = None) -> Hypotheses:
    """Project the frame's features for the particle states x (N, 6) = (b, w).

    ``extrinsic`` C = [Rc tc; 0 1] (4x4, metres; None: the left camera): project
    through the camera C . E(x_n) instead (the stereo right camera, C = right_T_left,
    K = K2): camera_X = Rc (R(w_n) E_0 X + b_n) + tc, one more (3, 3) x (3, K N)
    product. ``R``: the particles' R(w) (3, 3, N) if already computed (the
    returned ``R`` is R(w_n) either way)."""
    V, r, on_shaft = geometry.V, geometry.r, geometry.on_shaft
    R = so3_exp_batch(x[:, 3:]) if R is None else R
    k = V.shape[1]
    # W[i, k, n] = sum_j R[i, j, n] V[j, k]: one GEMM, (3, 3, N) -> (3, K, N)
    W = np.matmul(V.T, R)
    b = np.ascontiguousarray(x[:, :3].T)  # (3, N)
    if extrinsic is not None:
        Rc, tc = np.asarray(extrinsic, float)[:3, :3], np.asarray(extrinsic, float)[:3, 3]
        W = (Rc @ W.reshape(3, -1)).reshape(W.shape)
        b = Rc @ b + tc[:, None]
    p0 = W[:, 0] + b
    rho, cos, sin, valid, inward = project_cylinder_batch(p0, W[:, 1], r, K, sides=True)
    M = len(on_shaft)
    pts = W[:, 2:2 + M] + b[:, None, :]  # (3, M, N)
    front = pts[2] > pinhole.Z_MIN
    u, v = pinhole.pixels(K, pts[0], pts[1], pts[2], behind=1e9)   # finite; not visible behind the camera
    nrm = W[:, 2 + M:2 + 2 * M]
    facing = (nrm * pts).sum(axis=0) < 0.0
    visible = front & (facing | ~on_shaft[:, None])
    h = Hypotheses(rho, cos, sin, valid, u, v, visible, R, inward=inward)
    if geometry.has_end:
        P = front_point((W[:, k - 1] + b).T, W[:, 1].T, r)       # (N, 3)
        h.end_u, h.end_v = pinhole.pixels(K, P[:, 0], P[:, 1], P[:, 2])   # behind the camera: NaN
    return h
