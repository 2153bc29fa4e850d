"""Line-parameter factor: one detected shaft line (rho_d, theta_d) against E.

For the polar observation models. With the projected limb line
L(E) = (A, B, C) (:mod:`factors.limb`) written WITHOUT canonicalisation as

    theta(E) = atan2(B, A),   rho(E) = -C / s,   s = |(A, B)|

the residual is the wrapped line difference (:func:`graphtrack.geometry.lines.line_difference`)

    r = (d_rho, d_theta) = (rho(E), theta(E)) - (rho_d, theta_d),  d_theta in [-pi/2, pi/2)

where the detected line is taken in whichever of its two representations
(rho_d, theta_d) / (-rho_d, theta_d + pi) is nearer in angle (so the wrap
never produces a 2 pi / sign jump), and the nearer projected limb (in the
whitened metric) is used, re-chosen at every evaluation; with the frame's
other detected line (a shared :class:`factors.limb.LimbPairing`) the two take
different limbs, the pairing with the smaller total whitened cost. Analytic Jacobian:

    d theta/dL = (-B, A, 0)/s^2,   d rho/dL = (C A/s^3, C B/s^3, -1/s)

(the representation flip only changes the constant part of r). Whitening by
(sigma_rho px, sigma_theta rad) and the robust kernel are a
``gtsam.noiseModel.Robust`` (2 residuals: per-line robustness is exactly what
GTSAM's robust model gives). Degenerate view: zero residual, zero Jacobian.
"""
from __future__ import annotations

import numpy as np

from factors.limb import LimbPairing, ShaftAxis, line_matrix
from factors.error_function import PoseErrorFunction
from factors.robust import RobustKernel, make_kernel
from graphtrack.geometry.lines import line_difference


class LineParameterError(PoseErrorFunction):
    def __init__(self, line: np.ndarray, axis: ShaftAxis, K: np.ndarray,
                 sigma_rho: float = 3.0, sigma_theta: float = 0.01, pairing: LimbPairing | None = None):
        self.rho_d, self.theta_d = (float(v) for v in np.asarray(line, float).ravel()[:2])
        self.axis = axis
        self.M = line_matrix(np.asarray(K, float))
        self.sig = np.array([sigma_rho, sigma_theta], float)
        self.limb = -1
        self.pairing = pairing if pairing is not None else LimbPairing()  # alone: the nearer limb
        self.slot = self.pairing.add(self)

    def _differences(self, L: np.ndarray):
        A, B, C = L[:, 0], L[:, 1], L[:, 2]
        s = np.hypot(A, B)
        return line_difference(-C / s, np.arctan2(B, A), self.rho_d, self.theta_d)

    def costs(self, L: np.ndarray) -> np.ndarray:
        """Whitened squared difference (2,) of the detected line to each limb of L (2, 3)."""
        drho, dth = self._differences(L)
        return (drho / self.sig[0]) ** 2 + (dth / self.sig[1]) ** 2

    def evaluate(self, E: np.ndarray, jacobian: bool = True):
        """Unwhitened residual (d_rho px, d_theta rad) and its (2, 6) Jacobian."""
        L, dL, valid = self.pairing.lines(E, self.axis, self.M, jacobian)
        if not valid:
            self.limb = -1
            return np.zeros(2), (np.zeros((2, 6)) if jacobian else None)
        A, B, C = L[:, 0], L[:, 1], L[:, 2]
        s = np.hypot(A, B)
        drho, dth = self._differences(L)
        i = self.pairing.limbs(E, L)[self.slot]
        self.limb = i
        r = np.array([drho[i], dth[i]])
        if not jacobian:
            return r, None
        a, b, c, si = A[i], B[i], C[i], s[i]
        dth_dL = np.array([-b, a, 0.0]) / si ** 2
        drho_dL = np.array([c * a / si ** 3, c * b / si ** 3, -1.0 / si])
        J = np.vstack([drho_dL @ dL[i], dth_dL @ dL[i]])
        return r, J



def line_parameter_factor(key: int, line, axis: ShaftAxis, K: np.ndarray, sigma_rho: float = 3.0,
                          sigma_theta: float = 0.01, kernel: RobustKernel | str | None = "cauchy",
                          pairing: LimbPairing | None = None):
    """gtsam.CustomFactor on Pose3 ``key`` for one detected line (rho, theta);
    ``pairing``: the frame's :class:`factors.limb.LimbPairing` (None: nearer limb)."""
    import gtsam

    fn = LineParameterError(line, axis, K, sigma_rho, sigma_theta, pairing)
    noise = make_kernel(kernel).gtsam_noise(gtsam.noiseModel.Diagonal.Sigmas(fn.sig))
    return gtsam.CustomFactor(noise, [key], fn)
