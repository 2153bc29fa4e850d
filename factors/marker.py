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
is predicted at its centre's projection, like a point marker, and stays a
candidate: visibility judged from a pose several mm off at start-up is itself
wrong: of 100 synthetic start-ups from prior-drawn hand-eye errors, 86 end
within 3 mm this way and 73 when hidden discs are dropped. Residuals are robustified per detection on ||z_j||
(:mod:`factors.robust`). Association: Hungarian (scipy
``linear_sum_assignment``) between detections and the markers' predictions
through the CURRENT E at every evaluation (so at each relinearisation); a pair
farther than ``gate`` px (default 20) or a marker behind the camera leaves
detection j unassociated: z_j = 0, zero Jacobian. One factor per
frame carries all detections (one Python callback).

Analytic Jacobian (xi = (omega, v), gtsam's right perturbation E Exp(xi)):

    dpi/dX = A = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]],
    d pi(X_i)/d omega = rows P_i x (A R)_r,   d pi(X_i)/dv = A R
    d g_i/d omega = (R^T t) x n_i,   d g_i/dv = -n_i          (g_i = -N_i . X_i)
    d Z_i/d omega = P_i x R_3,   d Z_i/dv = R_3                (R_3: R's third row)
    d w_i = dg_i / Z_i^3 - 3 g_i dZ_i / Z_i^4                  (0 where g_i <= 0)
    d c = sum_i [(pi(X_i) - c) d w_i + w_i d pi(X_i)] / sum_i w_i
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from factors.error_function import PoseErrorFunction
from factors.robust import RobustKernel, make_kernel


def project_markers(E: np.ndarray, points: np.ndarray, K: np.ndarray):
    """Pixels (M, 2), camera points (M, 3) of base points (M, 3) through E."""
    X = points @ E[:3, :3].T + E[:3, 3]
    Z = np.where(X[:, 2] > 1e-9, X[:, 2], 1e-9)
    u = np.stack([K[0, 0] * X[:, 0] / Z + K[0, 2], K[1, 1] * X[:, 1] / Z + K[1, 2]], -1)
    return u, X


def associate(predicted: np.ndarray, detected: np.ndarray, gate: float = 20.0,
              usable: np.ndarray | None = None) -> np.ndarray:
    """Hungarian association: a (N,) marker index per detection, -1 if none within ``gate`` px."""
    a = -np.ones(len(detected), int)
    if len(detected) == 0 or len(predicted) == 0:
        return a
    D = np.linalg.norm(detected[:, None, :] - predicted[None, :, :], axis=-1)
    if usable is not None:
        D[:, ~usable] = 1e9
    rows, cols = linear_sum_assignment(D)
    ok = D[rows, cols] <= gate
    a[rows[ok]] = cols[ok]
    return a


class MarkerError(PoseErrorFunction):
    """The residual of the module doc. ``discs`` = (samples (M, S, 3), normals
    (M, S, 3)), base frame, or None (point markers); a marker whose normals are
    all zero is a point at samples[k, 0]."""

    def __init__(self, detections: np.ndarray, points: np.ndarray, K: np.ndarray, sigma: float = 2.0,
                 gate: float = 20.0, kernel: RobustKernel | str | None = "cauchy", discs=None):
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
        """Predicted pixels c (M, 2), usable (M,), and d c / d xi (M, 2, 6) when asked."""
        R, t = E[:3, :3], E[:3, 3]
        P = self.samples                                         # (M, S, 3)
        X = P @ R.T + t
        Z = X[..., 2]
        front = Z > 1e-6
        Zs = np.where(front, Z, 1.0)
        fx, fy = self.K[0, 0], self.K[1, 1]
        u = np.stack([fx * X[..., 0] / Zs + self.K[0, 2], fy * X[..., 1] / Zs + self.K[1, 2]], -1)
        w = np.ones(Z.shape)
        g = None
        if self.normals is not None and self.disc.any():
            n = self.normals
            g = -((n @ R.T) * X).sum(-1)
            w = np.where(self.disc[:, None], np.where(front & (g > 0), g / Zs ** 3, 0.0), 1.0)
        W = w.sum(-1)
        usable = np.all(front, axis=1)
        hidden = usable & (W <= 0)
        if hidden.any():         # a hidden disc: its centre, as a point marker (see the module doc)
            w = np.where(hidden[:, None], 0.0, w)
            w[hidden, 0] = 1.0
            P = P.copy()
            P[hidden, 0] = self.P[hidden]
            u = u.copy()
            Xc = self.P[hidden] @ R.T + t
            u[hidden, 0] = np.stack([fx * Xc[:, 0] / Xc[:, 2] + self.K[0, 2],
                                     fy * Xc[:, 1] / Xc[:, 2] + self.K[1, 2]], -1)
            X, Zs = X.copy(), Zs.copy()
            X[hidden, 0], Zs[hidden, 0] = Xc, Xc[:, 2]
            if g is not None:
                g = np.where(hidden[:, None], 0.0, g)
            W = w.sum(-1)
        Wd = np.where(W > 0, W, 1.0)
        c = (w[..., None] * u).sum(-2) / Wd[:, None]
        if not jacobian:
            return c, usable, None
        A = np.zeros(X.shape[:-1] + (2, 3))
        A[..., 0, 0] = fx / Zs
        A[..., 0, 2] = -fx * X[..., 0] / Zs ** 2
        A[..., 1, 1] = fy / Zs
        A[..., 1, 2] = -fy * X[..., 1] / Zs ** 2
        AR = A @ R                                               # (M, S, 2, 3)
        du = np.concatenate([np.cross(P[..., None, :], AR), AR], -1)  # (M, S, 2, 6)
        dc = (w[..., None, None] * du).sum(1)
        if g is not None:
            n = self.normals
            ct = R.T @ t
            dg = np.concatenate([np.cross(ct, n), -n], -1)        # (M, S, 6)
            dZ = np.concatenate([np.cross(P, R[2]), np.broadcast_to(R[2], P.shape)], -1)
            live = (self.disc[:, None] & front & (g > 0))[..., None]
            dw = np.where(live, dg / Zs[..., None] ** 3 - 3.0 * (g / Zs ** 4)[..., None] * dZ, 0.0)
            dc = dc + np.einsum("msr,msk->mrk", u - c[:, None, :], dw)
        return c, usable, dc / Wd[:, None, None]

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
                  sigma: float = 2.0, gate: float = 20.0,
                  kernel: RobustKernel | str | None = "cauchy", discs=None):
    """gtsam.CustomFactor on Pose3 ``key`` for a frame's marker detections (N, 2); None if
    none. ``discs``: painted-disc samples and normals (see :class:`MarkerError`)."""
    import gtsam

    detections = np.asarray(detections, float).reshape(-1, 2)
    points = np.asarray(points, float).reshape(-1, 3)
    if len(detections) == 0 or len(points) == 0:
        return None
    fn = MarkerError(detections, points, K, sigma, gate, kernel, discs)
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(fn.dim), [key], fn)
