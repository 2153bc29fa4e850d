"""Marker reprojection factor: all of one frame's marker detections against E.

Data: the markers' base-frame points P_k (k = 1..M, forward kinematics of the
frame's readings), the detected centroids u_j (j = 1..N, undistorted px) and K.
For X_k = R P_k + t (camera frame) the predicted pixel is

    pi(X) = (fx X/Z + cx, fy Y/Z + cy)

and the residual of detection j, associated with marker a(j), is

    z_j = (c_a(j)(E) - u_j) / sigma                (2 per detection)

with c_k = pi(X_k) for a point marker. A painted disc (``discs``: its surface
samples P_ki and outward normals n_ki, base frame,
:func:`graphtrack.geometry.painted_marker.painted_disc`) is predicted by the
centroid of its image, c_k = sum_i w_i pi(X_ki) / sum_i w_i with
w_i = max(0, -N_ki . X_ki) / Z_ki^3, N_ki = R n_ki (see
:mod:`graphtrack.geometry.painted_marker`). A disc hidden at E (every w_i = 0)
is predicted at its centre's projection, like a point marker (a step of ~1 px
as the last sample turns away: 1.1 mm disc, 4 mm shaft radius, 10 cm), and
stays an association candidate (docs/decisions/painted-disc-markers.md).
Residuals are robustified per detection on ||z_j||
(:mod:`factors.robust`). Association: Hungarian (scipy
``linear_sum_assignment``, on distances capped at the gate) between detections and the markers' predictions
through the CURRENT E at every evaluation (so at each relinearisation); a pair
farther than ``gate`` px (default 20) or a marker behind the camera leaves
detection j unassociated: z_j = 0, zero Jacobian. One factor per
frame carries all detections (one Python callback).

Analytic Jacobian (xi = (omega, v), gtsam's right perturbation E Exp(xi)):

    dpi/dX = A = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]]   (:mod:`graphtrack.geometry.pinhole`),
    d pi(X_i)/d omega = rows P_i x (A R)_r,   d pi(X_i)/dv = A R
    d g_i/d omega = (R^T t) x n_i,   d g_i/dv = -n_i          (g_i = -N_i . X_i)
    d Z_i/d omega = P_i x R_3,   d Z_i/dv = R_3                (R_3: R's third row)
    d w_i = dg_i / Z_i^3 - 3 g_i dZ_i / Z_i^4                  (0 where g_i <= 0)
    d c = sum_i [(pi(X_i) - c) d w_i + w_i d pi(X_i)] / sum_i w_i
"""
from __future__ import annotations

import gtsam
import numpy as np
from scipy.optimize import linear_sum_assignment

from factors.error_function import PoseErrorFunction
from factors.robust import RobustKernel, make_kernel
from graphtrack.geometry import pinhole
from graphtrack.geometry.se3 import skew


def associate(predicted: np.ndarray, detected: np.ndarray, gate: float,
              usable: np.ndarray | None = None) -> np.ndarray:
    """Hungarian association: a (N,) marker index per detection, -1 if none within ``gate`` px.

    The assignment minimises sum_j min(d_j, gate) (d_j: detection j's distance to its
    marker), the particle filter's marker cost (an unmatched detection costs the gate):
    a pair beyond the gate costs the same whichever marker it is, so detections far
    from every marker (a highlight, a blob on the tissue) do not move the near ones'
    pairing (docs/decisions/smoother-marker-gate.md)."""
    a = -np.ones(len(detected), int)
    if len(detected) == 0 or len(predicted) == 0:
        return a
    D = np.linalg.norm(detected[:, None, :] - predicted[None, :, :], axis=-1)
    if usable is not None:
        D[:, ~usable] = np.inf
    rows, cols = linear_sum_assignment(np.minimum(D, min(float(gate), 1e9)))
    ok = D[rows, cols] <= gate
    a[rows[ok]] = cols[ok]
    return a


class MarkerError(PoseErrorFunction):
    """The residual of the module doc. ``discs`` = (samples (M, S, 3), normals
    (M, S, 3)), base frame, or None (point markers); a marker whose normals are
    all zero is a point, predicted at the mean projection of its samples (all of
    them the point, as :func:`graphtrack.robot.features.marker_discs` makes them)."""

    def __init__(self, detections: np.ndarray, points: np.ndarray, K: np.ndarray, sigma: float,
                 gate: float, kernel: RobustKernel | str | None, discs=None):
        self.u = np.asarray(detections, float).reshape(-1, 2)
        self.P = np.asarray(points, float).reshape(-1, 3)
        self.K = np.asarray(K, float)
        self.sigma = float(sigma)
        self.gate = float(gate)
        self.kernel = make_kernel(kernel)
        self.assoc = -np.ones(len(self.u), int)
        if discs is None:
            self.samples, self.normals, self.disc = self.P[:, None, :], None, np.zeros(len(self.P), bool)
        else:
            self.samples = np.asarray(discs[0], float).reshape(len(self.P), -1, 3)
            self.normals = np.asarray(discs[1], float).reshape(self.samples.shape)
            self.disc = np.any(self.normals != 0.0, axis=(1, 2))

    @property
    def dim(self) -> int:
        return 2 * len(self.u)

    def predict(self, E: np.ndarray, jacobian: bool = False):
        """Predicted pixels c (M, 2), usable (M,), and d c / d xi (M, 2, 6) when asked.

        The samples of all markers are one flat (M S, 3) array (one numpy call
        per step: this runs at every linearisation of every frame)."""
        R, t = E[:3, :3], E[:3, 3]
        M, S = self.samples.shape[:2]

        def camera(P):   # camera points, 1/Z and pixels (finite behind the camera: masked below)
            X = P @ R.T + t
            iz = pinhole.inverse_depth(X[:, 2], 1.0)
            return X, iz, pinhole.project(self.K, X, iz=iz)

        P = self.samples.reshape(-1, 3)
        X, iz, u = camera(P)
        front = X[:, 2] > pinhole.Z_MIN
        usable = front.reshape(M, S).all(1)
        if self.normals is None or not self.disc.any():
            c = u.reshape(M, S, 2).mean(1)
            w = g = None
            W = np.full(M, float(S))
        else:
            n = self.normals.reshape(-1, 3)
            g = -np.einsum("ij,ij->i", n @ R.T, X)
            live = np.repeat(self.disc, S) & front & (g > 0)
            w = np.where(live, g * iz ** 3, 0.0)
            w[~np.repeat(self.disc, S)] = 1.0
            W = w.reshape(M, S).sum(1)
            hidden = usable & (W <= 0)
            if hidden.any():     # a hidden disc: its centre, as a point marker (see the module doc)
                rows = np.flatnonzero(np.repeat(hidden, S)).reshape(-1, S)[:, 0]
                P = P.copy()
                P[rows] = self.P[hidden]
                X, iz, u = camera(P)
                w[rows] = 1.0
                live[rows] = False
                W = w.reshape(M, S).sum(1)
            Wd = np.where(W > 0, W, 1.0)
            c = (w[:, None] * u).reshape(M, S, 2).sum(1) / Wd[:, None]
        if not jacobian:
            return c, usable, None
        # d u / d xi = A [-R [p]x, R], A = dpi/dX (zero at (0, 1), (1, 0)); row r of -R [p]x
        # is p x R_r = p @ [R_r]x (cheaper than np.cross on every call)
        A = pinhole.jacobian(self.K, X, iz=iz)
        a00, a02, a11, a12 = A[:, 0, 0, None], A[:, 0, 2, None], A[:, 1, 1, None], A[:, 1, 2, None]
        PxR = [P @ skew(R[r]) for r in range(3)]
        du = np.empty((len(P), 2, 6))
        du[:, 0, :3] = a00 * PxR[0] + a02 * PxR[2]
        du[:, 1, :3] = a11 * PxR[1] + a12 * PxR[2]
        du[:, 0, 3:] = a00 * R[0] + a02 * R[2]
        du[:, 1, 3:] = a11 * R[1] + a12 * R[2]
        if w is None:
            return c, usable, du.reshape(M, S, 2, 6).mean(1)
        dc = (w[:, None, None] * du).reshape(M, S, 2, 6).sum(1)
        if live.any():
            dg = np.concatenate([-(n @ skew(R.T @ t)), -n], 1)          # (R^T t) x n, -n
            dZ = np.concatenate([PxR[2], np.broadcast_to(R[2], P.shape)], 1)
            dw = np.where(live[:, None], dg * (iz ** 3)[:, None] - (3.0 * g * iz ** 4)[:, None] * dZ, 0.0)
            r = u - np.repeat(c, S, axis=0)
            dc += (r[:, :, None] * dw[:, None, :]).reshape(M, S, 2, 6).sum(1)
        return c, usable, dc / np.where(W > 0, W, 1.0)[:, None, None]

    def evaluate(self, E: np.ndarray, jacobian: bool = True):
        N = len(self.u)
        pred, usable, dc = self.predict(E, jacobian)
        a = associate(pred, self.u, self.gate, usable=usable)
        self.assoc = a
        z = np.zeros((N, 2))
        J = np.zeros((N, 2, 6)) if jacobian else None
        j = np.flatnonzero(a >= 0)
        if len(j):
            k = a[j]
            z[j] = (pred[k] - self.u[j]) / self.sigma
            if jacobian:
                J[j] = dc[k] / self.sigma
        e, Jr = self.kernel.apply(z, J)
        return e.reshape(-1), (Jr.reshape(-1, 6) if jacobian else None)


def marker_factor(key: int, detections: np.ndarray, points: np.ndarray, K: np.ndarray,
                  sigma: float, gate: float,
                  kernel: RobustKernel | str | None, discs=None,
                  extrinsic: np.ndarray | None = None):
    """gtsam.CustomFactor on Pose3 ``key`` for a frame's marker detections (N, 2); None if
    none. ``discs``: painted-disc samples and normals (see :class:`MarkerError`);
    ``extrinsic``: the observing camera from the left (:mod:`factors.error_function`)."""
    detections = np.asarray(detections, float).reshape(-1, 2)
    points = np.asarray(points, float).reshape(-1, 3)
    if len(detections) == 0 or len(points) == 0:
        return None
    fn = MarkerError(detections, points, K, sigma, gate, kernel, discs)
    fn.extrinsic = None if extrinsic is None else np.asarray(extrinsic, float)
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(fn.dim), [key], fn)
