"""Marker reprojection factor: all of one frame's marker detections against E.

Data: the markers' base-frame points P_k (k = 1..M, forward kinematics of the
frame's readings), the detected centroids u_j (j = 1..N, undistorted px) and K.
For X_k = R P_k + t (camera frame) the predicted pixel is

    pi(X) = (fx X/Z + cx, fy Y/Z + cy)

and the residual of detection j, associated with marker a(j), is

    z_j = (pi(X_a(j)) - u_j) / sigma                (2 per detection)

robustified per detection on ||z_j|| (:mod:`factors.robust`). Association:
Hungarian (scipy ``linear_sum_assignment``) between detections and the markers
projected through the CURRENT E at every evaluation (so at each
relinearisation); a pair farther than ``gate`` px (default 20) or a marker
behind the camera leaves detection j unassociated: z_j = 0, zero Jacobian.
One factor per frame carries all detections (one Python callback).

Analytic Jacobian (xi = (omega, v)):

    dpi/dX = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]],   dX/dxi = [-R [P]x, R]
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
    def __init__(self, detections: np.ndarray, points: np.ndarray, K: np.ndarray, sigma: float = 2.0,
                 gate: float = 20.0, kernel: RobustKernel | str | None = "cauchy"):
        self.u = np.asarray(detections, float).reshape(-1, 2)
        self.P = np.asarray(points, float).reshape(-1, 3)
        self.K = np.asarray(K, float)
        self.sigma = float(sigma)
        self.gate = float(gate)
        self.kernel = make_kernel(kernel)
        self.assoc = -np.ones(len(self.u), int)

    @property
    def dim(self) -> int:
        return 2 * len(self.u)

    def evaluate(self, E: np.ndarray, jacobian: bool = True):
        N = len(self.u)
        pred, X = project_markers(E, self.P, self.K)
        a = associate(pred, self.u, self.gate, usable=X[:, 2] > 1e-6)
        self.assoc = a
        z = np.zeros((N, 2))
        J = np.zeros((N, 2, 6)) if jacobian else None
        j = np.flatnonzero(a >= 0)
        if len(j):
            k = a[j]
            z[j] = (pred[k] - self.u[j]) / self.sigma
            if jacobian:
                R = E[:3, :3]
                Xk, Pk = X[k], self.P[k]
                Z = Xk[:, 2]
                fx, fy = self.K[0, 0], self.K[1, 1]
                dpi = np.zeros((len(j), 2, 3))
                dpi[:, 0, 0] = fx / Z
                dpi[:, 0, 2] = -fx * Xk[:, 0] / Z ** 2
                dpi[:, 1, 1] = fy / Z
                dpi[:, 1, 2] = -fy * Xk[:, 1] / Z ** 2
                # -R [P]x w = R (w x P) ... : -R skew(P) as (n,3,3)
                sk = np.zeros((len(j), 3, 3))
                sk[:, 0, 1], sk[:, 0, 2] = -Pk[:, 2], Pk[:, 1]
                sk[:, 1, 0], sk[:, 1, 2] = Pk[:, 2], -Pk[:, 0]
                sk[:, 2, 0], sk[:, 2, 1] = -Pk[:, 1], Pk[:, 0]
                dX = np.concatenate([-np.einsum("ij,njk->nik", R, sk),
                                     np.broadcast_to(R, (len(j), 3, 3))], -1)
                J[j] = dpi @ dX / self.sigma
        e, Jr = self.kernel.apply(z, J)
        return e.reshape(-1), (Jr.reshape(-1, 6) if jacobian else None)



def marker_factor(key: int, detections: np.ndarray, points: np.ndarray, K: np.ndarray,
                  sigma: float = 2.0, gate: float = 20.0,
                  kernel: RobustKernel | str | None = "cauchy"):
    """gtsam.CustomFactor on Pose3 ``key`` for a frame's marker detections (N, 2); None if none."""
    import gtsam

    detections = np.asarray(detections, float).reshape(-1, 2)
    points = np.asarray(points, float).reshape(-1, 3)
    if len(detections) == 0 or len(points) == 0:
        return None
    fn = MarkerError(detections, points, K, sigma, gate, kernel)
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(fn.dim), [key], fn)
