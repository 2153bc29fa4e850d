"""Painted-disc markers in the particle filter: detections moved to their discs' centres.

The particle filter predicts a marker at the projection pi(P_k) of its centre (the
paper's point marker), while the detector reports the centroid c_k of its blob,
which for a painted disc on the shaft lies off pi(P_k) by up to several px when the
disc is seen obliquely or near a silhouette
(:mod:`graphtrack.geometry.painted_marker`). The offset

    delta_k(E) = c_k(E) - pi(P_k; E)          (px, undistorted)

changes slowly with E (1 mm and 0.5 deg away it moves typically by <= 0.05 px, up to
~0.2 px near grazing; docs/decisions/painted-disc-markers.md), so it is taken once per frame and image at
the filter's estimate E_hat, and each detection u_j paired with marker k (Hungarian,
:func:`factors.marker.associate`, at the centroids c_k(E_hat), within the marker
gate) is replaced by u_j - delta_k: every hypothesis is then scored against where its
point model expects the disc's centre. A disc hidden at E_hat (every sample facing
away) and a detection paired with none are left as they are; a point marker (delta =
0) takes part in the pairing, so that its detection stays where it is, unless the
likelihood does not see it at E_hat (``seen``: e.g. on the shaft's far side).

The discs are sampled once (:func:`graphtrack.robot.features.marker_discs`), in the
frames of the links they are painted on; a frame moves them by its links' poses.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from factors.marker import associate
from graphtrack.geometry import pinhole
from graphtrack.geometry.painted_marker import disc_centroid
from graphtrack.robot.features import base_features, marker_discs
from graphtrack.robot.kinematics import link_transforms


class DiscOffsets:
    """The painted discs of ``robot``'s point features, sampled in their links' frames:
    samples X and outward normals N (M, S, 3), centres P (M, 3); ``available`` is False
    when no point feature is a disc (nothing then moves)."""

    def __init__(self, robot):
        self.robot = robot
        q0 = np.zeros(robot.n_joints)
        feats = base_features(robot, q0)
        discs = marker_discs(robot, feats)
        self.available = discs is not None
        if not self.available:
            return
        self.links = np.array([p.link for p in robot.point_features])
        inv = np.linalg.inv(link_transforms(robot, q0)[self.links])       # link_T_base (M, 4, 4)
        R, t = inv[:, :3, :3], inv[:, :3, 3]
        self.X = np.einsum("kij,ksj->ksi", R, discs[0]) + t[:, None, :]
        self.N = np.einsum("kij,ksj->ksi", R, discs[1])
        self.P = np.einsum("kij,kj->ki", R, np.asarray(feats.points, float).reshape(-1, 3)) + t
        self.point = ~np.any(self.N != 0, axis=(1, 2))      # (M,) a point marker: no disc
        self._poses = (None, None)

    def link_poses(self, q: np.ndarray) -> np.ndarray:
        """base_T_link (M, 4, 4) of each marker's link at reading q (the last q's kept;
        :class:`graphtrack.estimate.pf.projection.FrameGeometry` carries the same as
        ``marker_links``)."""
        key = np.asarray(q, float).tobytes()
        if self._poses[0] != key:
            self._poses = (key, link_transforms(self.robot, np.asarray(q, float))[self.links])
        return self._poses[1]

    def offsets(self, links: np.ndarray, T: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(c (M, 2), delta (M, 2)) px with the markers' links at ``links`` (base_T_link,
        (M, 4, 4)) for the camera-from-base transform T (4x4) and intrinsics K: the
        discs' image centroids and their offsets from the centres' projections; rows of
        NaN for a hidden disc or a centre behind the camera, delta = 0 for a point marker."""
        C = T @ links                                                    # camera_T_link (M, 4, 4)
        Rt, t = C[:, :3, :3].transpose(0, 2, 1), C[:, None, :3, 3]
        c = disc_centroid(np.matmul(self.X, Rt) + t, np.matmul(self.N, Rt), K)
        P = (np.matmul(self.P[:, None, :], Rt) + t)[:, 0]
        centre = pinhole.project(K, P)                                   # NaN behind the camera
        c[self.point] = centre[self.point]                 # a point marker: its detection is its centre
        return c, c - centre

    def centre_equivalent(self, observation, q: np.ndarray, T: np.ndarray, K: np.ndarray, gate: float,
                          links: np.ndarray | None = None, seen: np.ndarray | None = None):
        """``observation`` with each paired detection moved by -delta_k (module doc) at
        reading q for the camera T (camera-from-base, 4x4), K; the same object when
        nothing moves. ``links``: the markers' link poses at q when the caller has them
        (:meth:`link_poses`); ``seen`` (M,): the markers the likelihood sees at T (the
        particle filter's :func:`graphtrack.estimate.pf.projection.project` ``visible``),
        None: all; a point marker it does not see takes no detection."""
        if observation is None or not self.available or len(observation.markers) == 0:
            return observation
        c, delta = self.offsets(self.link_poses(q) if links is None else links, T, K)
        usable = np.all(np.isfinite(delta), axis=1)
        if seen is not None:
            usable &= seen | ~self.point
        if not usable.any():
            return observation
        det = np.asarray(observation.markers, float)
        pair = associate(np.where(usable[:, None], c, 0.0), det[:, :2], gate, usable)
        ok = pair >= 0
        if not ok.any():
            return observation
        moved = det.copy()
        moved[ok, :2] -= delta[pair[ok]]
        return dataclasses.replace(observation, markers=moved)
