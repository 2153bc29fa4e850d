"""Shaft-end factor: where the shaft visibly ends, along its image, against E.

Data: the shaft's distal end centre c_b and unit axis direction a_b in the base
frame (forward kinematics of the frame's readings), its radius r, K, and the
detected end p (undistorted px) with the band's unit distal direction d (image;
:mod:`graphtrack.detect.shaft_end`). With c = R c_b + t, a = R a_b and the front
point of the end's rim P = c + r u (:mod:`graphtrack.geometry.shaft_end`), the
residual is the offset along the shaft's image,

    z = (d . (pi(P) - p) + e) / sigma                                (1 per frame)

(across the shaft the silhouette lines already say where it is), e the end offset of
the frame's edge-bias vector b in stereo frames (:mod:`factors.edge_bias`, its component
``END_OFFSET``; e = 0 in mono frames or without the state): the detected end
p = pi(P) + e d + noise. An end detector errs along the shaft by nearly the same amount
in every frame (where the dark shaft meets the wrist's shading and blur), so e is a
slowly varying state, not white noise: the end fixes the slide to within e's spread,
not to sigma / sqrt(frames) (docs/decisions/end-offset-state.md). Robustified on |z|
(:mod:`factors.robust`).

Analytic Jacobian, xi = (omega, v), gtsam's right perturbation E Exp(xi):

    dc/domega = -R [c_b]x,   dc/dv = R,   da/domega = -R [a_b]x,   da/dv = 0
    dP = dP/dc dc + dP/da da,   dpi/dP = A (:mod:`graphtrack.geometry.pinhole`)
    dz/dxi = d^T A dP / sigma,   dz/de = 1 / sigma
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.edge_bias import BIAS_DIM, END_OFFSET
from factors.error_function import PoseBiasErrorFunction
from factors.robust import RobustKernel, make_kernel
from graphtrack.geometry import pinhole
from graphtrack.geometry.se3 import skew
from graphtrack.geometry.shaft_end import front_point_jacobian


class ShaftEndError(PoseBiasErrorFunction):
    """The residual of the module doc (dimension 1); on E alone or, with ``bias``, on (E, b)."""

    def __init__(self, detection: np.ndarray, direction: np.ndarray, centre: np.ndarray,
                 axis: np.ndarray, radius: float, K: np.ndarray, sigma: float,
                 kernel: RobustKernel | str | None, bias: bool = False):
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
        self.on_bias = bool(bias)

    def offset(self, E: np.ndarray, jacobian: bool = False):
        """d . (pi(P) - p) (px) and its derivative (6,) when asked (None if P is behind the camera)."""
        R, t = E[:3, :3], E[:3, 3]
        c, a = R @ self.c_b + t, R @ self.a_b
        P, dP_dc, dP_da = front_point_jacobian(c, a, self.r)
        if P[2] <= pinhole.Z_MIN:
            return None, None
        s = float(self.d @ (pinhole.project(self.K, P) - self.p))
        if not jacobian:
            return s, None
        A = pinhole.jacobian(self.K, P)
        dc = np.hstack([-R @ skew(self.c_b), R])
        da = np.hstack([-R @ skew(self.a_b), np.zeros((3, 3))])
        return s, self.d @ A @ (dP_dc @ dc + dP_da @ da)

    def evaluate(self, E: np.ndarray, jacobian: bool = True, b: np.ndarray | None = None):
        """z (1,) and, when asked, dz/dxi (1, 6), or with b (BIAS_DIM,) [dz/dxi, dz/db] (1, 6 + BIAS_DIM)."""
        ncols = 6 if b is None else 6 + BIAS_DIM
        s, ds = self.offset(E, jacobian)
        if s is None:
            return np.zeros(1), (np.zeros((1, ncols)) if jacobian else None)
        if b is not None:
            s = s + float(b[END_OFFSET])
        J = None
        if jacobian:
            J = np.zeros((1, ncols))
            J[0, :6] = ds / self.sigma
            if b is not None:
                J[0, 6 + END_OFFSET] = 1.0 / self.sigma
        return self.kernel.apply_scalar(np.array([s / self.sigma]), J)


def shaft_end_factor(key: int, detection: np.ndarray, direction: np.ndarray, centre: np.ndarray,
                     axis: np.ndarray, radius: float, K: np.ndarray, sigma: float,
                     kernel: RobustKernel | str | None, extrinsic: np.ndarray | None = None,
                     bias_key: int | None = None):
    """gtsam.CustomFactor on Pose3 ``key`` for one frame's detected shaft end (module
    doc); ``extrinsic``: the observing camera from the left (:mod:`factors.error_function`);
    ``bias_key``: the frame's edge-bias vector, whose end offset e the factor is on too
    (None: e = 0)."""
    fn = ShaftEndError(detection, direction, centre, axis, radius, K, sigma, kernel, bias=bias_key is not None)
    fn.extrinsic = None if extrinsic is None else np.asarray(extrinsic, float)
    keys = [key] if bias_key is None else [key, bias_key]
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), keys, fn)
