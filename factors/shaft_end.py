"""Shaft-end factor: where the shaft visibly ends, along its image, against E.

Data: the shaft's distal end centre c_b and unit axis direction a_b in the base
frame (forward kinematics of the frame's readings), its radius r, K, and the
detected end p (undistorted px) with the band's unit distal direction d (image;
:mod:`graphtrack.detect.shaft_end`). With c = R c_b + t, a = R a_b and the front
point of the end's rim P = c + r u (:mod:`graphtrack.geometry.shaft_end`), the
residual is the offset along the shaft's image,

    z = d . (pi(P) - p) / sigma                                      (1 per frame)

(across the shaft the silhouette lines already say where it is). Robustified on
|z| (:mod:`factors.robust`).

Analytic Jacobian, xi = (omega, v), gtsam's right perturbation E Exp(xi):

    dc/domega = -R [c_b]x,   dc/dv = R,   da/domega = -R [a_b]x,   da/dv = 0
    dP = dP/dc dc + dP/da da,   dpi/dP = A = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]]
    dz/dxi = d^T A dP / sigma
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.error_function import PoseErrorFunction
from factors.robust import RobustKernel, make_kernel
from graphtrack.geometry.se3 import skew
from graphtrack.geometry.shaft_end import front_point_jacobian


class ShaftEndError(PoseErrorFunction):
    """The residual of the module doc (dimension 1)."""

    def __init__(self, detection: np.ndarray, direction: np.ndarray, centre: np.ndarray,
                 axis: np.ndarray, radius: float, K: np.ndarray, sigma: float,
                 kernel: RobustKernel | str | None):
        self.p = np.asarray(detection, float).reshape(2)
        d = np.asarray(direction, float).reshape(2)
        self.d = d / np.linalg.norm(d)
        self.c_b = np.asarray(centre, float).reshape(3)
        a = np.asarray(axis, float).reshape(3)
        self.a_b = a / np.linalg.norm(a)
        self.r = float(radius)
        self.K = np.asarray(K, float)
        self.sigma = float(sigma)
        self.kernel = make_kernel(kernel)

    def offset(self, E: np.ndarray, jacobian: bool = False):
        """d . (pi(P) - p) (px) and its derivative (6,) when asked (None if P is behind the camera)."""
        R, t = E[:3, :3], E[:3, 3]
        c, a = R @ self.c_b + t, R @ self.a_b
        P, dP_dc, dP_da = front_point_jacobian(c, a, self.r)
        X, Y, Z = P
        if Z <= 1e-6:
            return None, None
        fx, fy = self.K[0, 0], self.K[1, 1]
        u = np.array([fx * X / Z + self.K[0, 2], fy * Y / Z + self.K[1, 2]])
        s = float(self.d @ (u - self.p))
        if not jacobian:
            return s, None
        A = np.array([[fx / Z, 0.0, -fx * X / Z ** 2], [0.0, fy / Z, -fy * Y / Z ** 2]])
        dc = np.hstack([-R @ skew(self.c_b), R])
        da = np.hstack([-R @ skew(self.a_b), np.zeros((3, 3))])
        return s, self.d @ A @ (dP_dc @ dc + dP_da @ da)

    def evaluate(self, E: np.ndarray, jacobian: bool = True):
        s, ds = self.offset(E, jacobian)
        if s is None:
            return np.zeros(1), (np.zeros((1, 6)) if jacobian else None)
        J = None if not jacobian else (ds / self.sigma).reshape(1, 6)
        return self.kernel.apply_scalar(np.array([s / self.sigma]), J)


def shaft_end_factor(key: int, detection: np.ndarray, direction: np.ndarray, centre: np.ndarray,
                     axis: np.ndarray, radius: float, K: np.ndarray, sigma: float,
                     kernel: RobustKernel | str | None, extrinsic: np.ndarray | None = None):
    """gtsam.CustomFactor on Pose3 ``key`` for one frame's detected shaft end (module
    doc); ``extrinsic``: the observing camera from the left (:mod:`factors.error_function`)."""
    fn = ShaftEndError(detection, direction, centre, axis, radius, K, sigma, kernel)
    fn.extrinsic = None if extrinsic is None else np.asarray(extrinsic, float)
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [key], fn)
