"""Line-parameter factor: one detected shaft line (rho_d, theta_d) against E.

For the polar observation models. With the projected limb line L(E) = (A, B, C)
(:func:`graphtrack.geometry.cylinder.limb_line_coefficients`), not canonicalised
(:func:`graphtrack.geometry.cylinder.line_polar`),

    theta(E) = atan2(B, A),   rho(E) = -C / s,   s = |(A, B)|

the residual is the wrapped line difference (:func:`graphtrack.geometry.lines.line_difference`)

    r = (d_rho, d_theta) = (rho(E), theta(E)) - (rho_d, theta_d),  d_theta in [-pi/2, pi/2)

with the detected line in whichever representation, (rho_d, theta_d) or
(-rho_d, theta_d + pi), is nearer in angle (no 2 pi / sign jump). The limb is the
nearer one in the whitened metric, re-chosen at every evaluation; with the frame's
other line (a shared :class:`factors.limb.LimbPairing`) the two take different limbs,
the pairing of smaller total cost. Analytic Jacobian
(:func:`graphtrack.geometry.cylinder.line_polar_jacobian`; a flip only changes r's
constant part):

    d theta/dL = (-B, A, 0)/s^2,   d rho/dL = (C A/s^3, C B/s^3, -1/s)

Whitening by (sigma_rho px, sigma_theta rad) and the robust kernel: a
``gtsam.noiseModel.Robust`` on the 2 residuals. Degenerate view: zero residual and Jacobian.

Edge bias b = (l, l_s, w, w_s) px (:mod:`factors.edge_bias`; the factor is on (E, b)):
limb i is moved as the pixel models move their sets, by the offset o_i = w + sgn_i l
(into the shaft's image) at x0, the foot of the principal point on the detected line,
and turned by the slope k_i = (w_s + sgn_i l_s) / T per px along u, the detected
line's direction oriented like the shaft's reference direction (T = ``SLOPE_SCALE``).
With n = (A, B)/s, c = C/s the limb's signed-distance line, the biased line is

    L' = (n - k_i u, c - o_i + k_i u.x0)     (x on it: n.x + c = o_i + k_i u.(x - x0))

and theta, rho are taken of L' as above. (Anchored at x0, not a set's centroid: each
model family estimates its own b.) Lines are paired with limbs on E alone. b enters
nonlinearly through the slope (a 1-sigma slope of 3 px / 100 px: ~0.3 px of rho off
the first-order prediction, against sigma_rho = 3 px). Chain rule:
dn/d(A, B) = (I - n n^T)/s, dc/d(A, B, C) = (-C A/s^3, -C B/s^3, 1/s),
dL'/do_i = (0, 0, -1), dL'/dk_i = (-u, u.x0).

Why the lines are on the bias state: docs/decisions/edge-bias-state.md.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.edge_bias import BIAS_DIM, SLOPE_SCALE, limb_bias, limb_bias_jacobian
from factors.error_function import PoseBiasErrorFunction
from factors.limb import LimbPairing
from factors.robust import RobustKernel, make_kernel
from graphtrack.geometry.cylinder import ShaftAxis, line_matrix, line_polar, line_polar_jacobian
from graphtrack.geometry.lines import line_difference


class LineParameterError(PoseBiasErrorFunction):
    """The residual of the module doc; ``bias``: the factor is on (E, b), the edge-bias
    vector; ``direction``: the frame's reference direction of the shaft (2,) that
    orients u (:func:`factors.edge_bias.reference_direction`; None: +y)."""

    def __init__(self, line: np.ndarray, axis: ShaftAxis, K: np.ndarray,
                 sigma_rho: float, sigma_theta: float, pairing: LimbPairing | None = None,
                 bias: bool = False, direction: np.ndarray | None = None):
        self.rho_d, self.theta_d = (float(v) for v in np.asarray(line, float).ravel()[:2])
        self.axis = axis
        self.M = line_matrix(np.asarray(K, float))
        self.sig = np.array([sigma_rho, sigma_theta], float)
        self.limb = -1
        self.on_bias = bool(bias)    # the factor is on (E, b) (PoseBiasErrorFunction)
        self.b = np.zeros(BIAS_DIM)     # the bias the differences are taken with
        if self.on_bias:
            n = np.array([np.cos(self.theta_d), np.sin(self.theta_d)])
            c = np.asarray(K, float)[:2, 2]
            x0 = c - (n @ c - self.rho_d) * n                 # foot of the principal point
            u = np.array([-n[1], n[0]])
            ref = np.array([1e-9, 1.0]) if direction is None else np.asarray(direction, float)
            self.u = u if u @ ref >= 0 else -u
            self.ux0 = float(self.u @ x0)
        self.pairing = pairing if pairing is not None else LimbPairing()  # alone: the nearer limb
        self.slot = self.pairing.add(self)

    def biased(self, L: np.ndarray) -> np.ndarray:
        """L' (2, 3) of both limbs of L (2, 3) under the bias self.b (L itself without the state)."""
        if not self.on_bias:
            return L
        s = np.hypot(L[:, 0], L[:, 1])[:, None]
        ok = np.array([limb_bias(self.b, i) for i in range(2)])        # (2, 2): o_i, slope_i
        k = ok[:, 1:2] / SLOPE_SCALE
        return np.hstack([L[:, :2] / s - k * self.u, L[:, 2:] / s - ok[:, 0:1] + k * self.ux0])

    def _differences(self, L: np.ndarray, biased: bool = True):
        if biased:
            L = self.biased(L)
        rho, theta = line_polar(L)
        return line_difference(rho, theta, self.rho_d, self.theta_d)

    def costs(self, L: np.ndarray) -> np.ndarray:
        """Whitened squared difference (2,) of the detected line to each limb of L (2, 3),
        unbiased: the frame's lines are paired with the limbs on E alone, as the pixel
        sets are (a slope of a few sigma turns a line about x0, hundreds of px from the
        image origin, enough to swap the pairing, which b's Jacobian cannot see)."""
        drho, dth = self._differences(L, biased=False)
        return (drho / self.sig[0]) ** 2 + (dth / self.sig[1]) ** 2

    def evaluate(self, E: np.ndarray, jacobian: bool = True, b: np.ndarray | None = None):
        """Unwhitened residual (d_rho px, d_theta rad) and its Jacobian: (2, 6) d/dxi, or
        with the bias state (b given; required then) (2, 6 + BIAS_DIM) [d/dxi, d/db]."""
        if self.on_bias != (b is not None):
            raise ValueError("LineParameterError: b must be given exactly when the factor is on the edge-bias state")
        ncols = 6 if b is None else 6 + BIAS_DIM
        if b is not None:
            self.b = np.asarray(b, float)
        L, dL, valid = self.pairing.lines(E, self.axis, self.M, jacobian)
        if not valid:
            self.limb = -1
            return np.zeros(2), (np.zeros((2, ncols)) if jacobian else None)
        drho, dth = self._differences(L)
        i = self.pairing.limbs(E, L)[self.slot]
        self.limb = i
        r = np.array([drho[i], dth[i]])
        if not jacobian:
            return r, None
        dr_dLb = line_polar_jacobian(self.biased(L)[i])                  # d(rho, theta)/dL'
        if b is None:
            return r, dr_dLb @ dL[i]
        A, B, C = L[i]
        s = np.hypot(A, B)
        n = np.array([A, B]) / s
        dLb_dL = np.zeros((3, 3))
        dLb_dL[:2, :2] = (np.eye(2) - np.outer(n, n)) / s
        dLb_dL[2] = [-C * A / s ** 3, -C * B / s ** 3, 1.0 / s]
        dLb_dok = np.array([[0.0, -self.u[0]], [0.0, -self.u[1]], [-1.0, self.ux0]])   # d L'/d(o, k)
        dok_db = np.diag([1.0, 1.0 / SLOPE_SCALE]) @ limb_bias_jacobian(i)
        J = np.hstack([dr_dLb @ dLb_dL @ dL[i], dr_dLb @ dLb_dok @ dok_db])
        return r, J



def line_parameter_factor(key: int, line, axis: ShaftAxis, K: np.ndarray, sigma_rho: float,
                          sigma_theta: float, kernel: RobustKernel | str | None,
                          pairing: LimbPairing | None = None, bias_key: int | None = None,
                          direction: np.ndarray | None = None, extrinsic: np.ndarray | None = None):
    """gtsam.CustomFactor on Pose3 ``key`` for one detected line (rho, theta);
    ``extrinsic``: the observing camera from the left (:mod:`factors.error_function`);
    ``pairing``: the frame's :class:`factors.limb.LimbPairing` (None: nearer limb);
    with ``bias_key`` (the frame's edge-bias vector) on (key, bias_key), ``direction``
    the frame's reference direction of the shaft."""
    fn = LineParameterError(line, axis, K, sigma_rho, sigma_theta, pairing, bias_key is not None, direction)
    fn.extrinsic = None if extrinsic is None else np.asarray(extrinsic, float)
    noise = make_kernel(kernel).gtsam_noise(gtsam.noiseModel.Diagonal.Sigmas(fn.sig))
    keys = [key] if bias_key is None else [key, bias_key]
    return gtsam.CustomFactor(noise, keys, fn)
