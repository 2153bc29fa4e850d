"""The visible features of the tool, in the base frame and in the camera frame.

For a joint reading q~ the features are first placed in the PSM base frame
with the forward kinematics; N hypotheses of the lumped error E (N x 4 x 4)
then map them all into the camera frame at once:

    X_cam = E . base_T_link_j(q~) . X_link             (metres)

and the shaft cylinders project to their limb lines with
:func:`graphtrack.geometry.cylinder.project_cylinder`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.geometry.cylinder import project_cylinder
from graphtrack.robot.description import RobotDescription
from graphtrack.robot.kinematics import link_transforms
from graphtrack.geometry.painted_marker import disc_pattern, on_surface, painted_disc


@dataclass
class Features:
    """Feature geometry in one frame of reference (base or camera), leading axes (...).

    points: (..., P, 3) point features (markers) in robot.point_features order;
    shaft_p0, shaft_d: (..., S, 3) point on and unit direction of each shaft axis;
    shaft_r: (S,) radii; tip: (..., 3) or None; skeleton: (..., K, 2, 3);
    shaft_end: (..., S, 3) the centre of each shaft's distal end (robot.json ``end``,
    NaN for a shaft without one, :mod:`graphtrack.geometry.shaft_end`).
    """

    points: np.ndarray
    shaft_p0: np.ndarray
    shaft_d: np.ndarray
    shaft_r: np.ndarray
    tip: np.ndarray | None
    skeleton: np.ndarray
    shaft_end: np.ndarray | None = None

    def transformed(self, E: np.ndarray) -> "Features":
        """Apply E (..., 4, 4) (e.g. N hypotheses, N x 4 x 4) to every feature.

        Leading axes of E and of the features broadcast: base features of one
        reading (no leading axes) with E (N, 4, 4) give (N, ...) features.
        """
        E = np.asarray(E, dtype=float)
        R, t = E[..., :3, :3], E[..., :3, 3]

        def pts(x, extra):  # x: (..., *extra, 3)
            Rb = R.reshape(R.shape[:-2] + (1,) * extra + (3, 3))
            tb = t.reshape(t.shape[:-1] + (1,) * extra + (3,))
            return np.einsum("...ij,...j->...i", Rb, x) + tb

        def dirs(x, extra):
            Rb = R.reshape(R.shape[:-2] + (1,) * extra + (3, 3))
            return np.einsum("...ij,...j->...i", Rb, x)

        return Features(
            points=pts(self.points, 1),
            shaft_p0=pts(self.shaft_p0, 1),
            shaft_d=dirs(self.shaft_d, 1),
            shaft_r=self.shaft_r,
            tip=None if self.tip is None else pts(self.tip, 0),
            skeleton=pts(self.skeleton, 2),
            shaft_end=None if self.shaft_end is None else pts(self.shaft_end, 1),
        )


def base_features(robot: RobotDescription, q: np.ndarray) -> Features:
    """Features in the PSM base frame for joint vectors q (..., n_joints)."""
    L = link_transforms(robot, q)  # (..., n_links+1, 4, 4)

    def on_links(links, positions):
        if len(links) == 0:
            return np.zeros(L.shape[:-3] + (0, 3))
        T = L[..., np.asarray(links), :, :]
        p = np.asarray(positions, dtype=float)
        return np.einsum("...kij,kj->...ki", T[..., :3, :3], p) + T[..., :3, 3]

    def dir_on_links(links, directions):
        if len(links) == 0:
            return np.zeros(L.shape[:-3] + (0, 3))
        T = L[..., np.asarray(links), :, :]
        v = np.asarray(directions, dtype=float)
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        return np.einsum("...kij,kj->...ki", T[..., :3, :3], v)

    pf = robot.point_features
    sf = robot.shaft_features
    sk = robot.skeleton
    tip_feat = robot.tool_tip
    tip_xyz = None
    if tip_feat is not None:
        tip_xyz = on_links([tip_feat.link], [tip_feat.position])[..., 0, :]
    skel = np.stack([on_links([s.link1 for s in sk], [s.position1 for s in sk]),
                     on_links([s.link2 for s in sk], [s.position2 for s in sk])], axis=-2)
    shaft_p0 = on_links([s.link for s in sf], [s.position for s in sf])
    shaft_d = dir_on_links([s.link for s in sf], [s.direction for s in sf])
    ends = np.array([np.nan if s.end is None else s.end for s in sf], dtype=float)
    return Features(
        points=on_links([p.link for p in pf], [p.position for p in pf]),
        shaft_p0=shaft_p0,
        shaft_d=shaft_d,
        shaft_r=np.array([s.radius for s in sf], dtype=float),
        tip=tip_xyz,
        skeleton=skel,
        shaft_end=shaft_p0 + ends[:, None] * shaft_d,
    )


def camera_features(robot: RobotDescription, q: np.ndarray, E: np.ndarray) -> Features:
    """Features in the camera frame: E (..., 4, 4) applied to base_features(q)."""
    return base_features(robot, q).transformed(E)


def shaft_lines(cam: Features, K: np.ndarray, shaft: int = 0):
    """Limb lines of shaft ``shaft`` in undistorted pixels for camera-frame features.

    Returns rho (..., 2) px, theta (..., 2) rad, valid (...,) — see
    :func:`graphtrack.geometry.cylinder.project_cylinder`.
    """
    return project_cylinder(cam.shaft_p0[..., shaft, :], cam.shaft_d[..., shaft, :],
                            cam.shaft_r[shaft], K)


def marker_discs(robot: RobotDescription, features: Features, n: int = 9):
    """Painted-disc samples and outward normals ((M, S, 3) each, the frame of
    ``features``, one joint reading) of the point features with a ``radius``
    (:func:`graphtrack.geometry.painted_marker.painted_disc`, n x n grid).

    A point feature is a disc when its radius is positive and it lies on the
    surface of a shaft feature of its own link (within 5 % of that radius);
    any other stays a point: its S samples are the point and its normals zero.
    None when no point feature is a disc.
    """
    P = np.asarray(features.points, float).reshape(-1, 3)
    radii = np.array([p.radius for p in robot.point_features], float)
    if len(P) == 0 or len(features.shaft_r) == 0 or not np.any(radii > 0):
        return None
    S = len(disc_pattern(1.0, n)[0])          # the same count for every radius
    X = np.repeat(P[:, None, :], S, axis=1)
    N = np.zeros_like(X)
    links = np.array([p.link for p in robot.point_features])
    todo = radii > 0
    found = False
    for s, sf in enumerate(robot.shaft_features):
        p0, d, r = features.shaft_p0[s], features.shaft_d[s], float(features.shaft_r[s])
        sel = todo & (links == sf.link)
        sel[sel] = on_surface(P[sel], p0, d, r)
        if sel.any():
            X[sel], N[sel] = painted_disc(P[sel], p0, d, r, radii[sel], n)
            found = True
        todo &= ~sel
    return (X, N) if found else None
