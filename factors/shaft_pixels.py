"""Point-to-projected-line factor: one shaft edge's pixel set against E.

Pixels p_j = (x_j, y_j), j = 1..m (undistorted px), against the projected limb line
(A, B, C) = L(E) of the shaft axis (fixed base-frame data of the frame's readings):

    z_j = (cos theta x_j + sin theta y_j - rho) / sigma
        = (A x_j + B y_j + C) / (s sigma),     s = |(A, B)|

(signed distance in px), robustified per pixel (:mod:`factors.robust`); one factor,
one Python callback, per edge and frame. Analytic Jacobian (right perturbation
xi = (omega, v)), h_j = (x_j, y_j, 1), dL/dxi from
:func:`graphtrack.geometry.cylinder.limb_line_coefficients`:

    dz_j/dxi = (h_j - z_j sigma (A, B, 0)/s) / (s sigma) . dL/dxi

(:func:`graphtrack.geometry.cylinder.pixel_residual_jacobian`). Limb assignment,
re-decided at every evaluation: alone, the limb of smaller robust cost; with the
frame's other edge (a shared :class:`LimbPairing`), the two take DIFFERENT limbs,
the pairing of smaller total cost (the cost is the minimum over assignments,
continuous in E). A degenerate view (``valid`` False): zero residual and Jacobian.

Edge bias (``bias=True``, :mod:`factors.edge_bias`): second key b = (l, l_s, w, w_s)
px; a pixel assigned to limb i has

    z_j = (R(p_j | theta_i(E), rho_i(E)) - c_j . (w + sgn_i l, w_s + sgn_i l_s)) / sigma,
    c_j = (1, t_j / T)       (t_j along the set, :func:`factors.edge_bias.bias_coefficients`)

and dz_j/db = -c_j . G_i / sigma, G_i = d(offset, slope)/db
(:func:`factors.edge_bias.limb_bias_jacobian`); the limb is assigned on E alone.

Tempering (``weight`` w in (0, 1]): cost w sum_j rho(z_j), i.e. e_j = sqrt(w) g(z_j),
the robust kernel still judging each pixel on sigma; w = n / m makes an m-pixel set
count as n independent pixels.

Decisions: docs/decisions/smoother-start-up.md (limb pairing),
pixel-effective-count.md, edge-bias-state.md.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.edge_bias import BIAS_DIM, bias_coefficients, limb_bias, limb_bias_jacobian
from factors.error_function import PoseBiasErrorFunction
from factors.limb import LimbPairing
from factors.robust import RobustKernel, make_kernel
from graphtrack.geometry.cylinder import ShaftAxis, line_matrix, pixel_residual_jacobian, pixel_residuals


class ShaftPixelsError(PoseBiasErrorFunction):
    """Typed error function of one edge's pixel set (call it like GTSAM does)."""

    def __init__(self, pixels: np.ndarray, axis: ShaftAxis, K: np.ndarray, sigma: float,
                 kernel: RobustKernel | str | None, pairing: LimbPairing | None = None,
                 weight: float = 1.0, bias: bool = False, direction: np.ndarray | None = None):
        self.pixels = np.asarray(pixels, float).reshape(-1, 2)
        self.C = bias_coefficients(self.pixels, direction) if bias else None   # (m, 2) or None
        self.h = np.hstack([self.pixels, np.ones((len(self.pixels), 1))])  # (m, 3)
        self.axis = axis
        self.M = line_matrix(np.asarray(K, float))
        self.sigma = float(sigma)
        self.kernel = make_kernel(kernel)
        self.limb = -1      # limb used at the last evaluation (0 / 1), -1: degenerate
        self.pairing = pairing if pairing is not None else LimbPairing()  # alone: the nearer limb
        self.slot = self.pairing.add(self)
        self._zL = self._z = None
        self.sqrt_w = float(np.sqrt(weight))

    @property
    def dim(self) -> int:
        return len(self.pixels)

    def whitened(self, L: np.ndarray) -> np.ndarray:
        """z (m, 2): the whitened residuals of the pixels against both limbs L (2, 3)
        (kept for the last L: the pairing's costs and the evaluation share them)."""
        if L is not self._zL:
            self._zL, self._z = L, pixel_residuals(self.h, L) / self.sigma
        return self._z

    def costs(self, L: np.ndarray) -> np.ndarray:
        """Robust cost (2,) of the pixel set against each limb of L (2, 3)."""
        return self.sqrt_w ** 2 * self.kernel.loss(np.abs(self.whitened(L))).sum(axis=0)

    def evaluate(self, E: np.ndarray, jacobian: bool = True, b: np.ndarray | None = None):
        """Residual e (m,) and its Jacobian (None without ``jacobian``) at 4x4 E:
        de/dxi (m, 6), or with the bias vector b (BIAS_DIM,) (``bias=True``) the
        (m, 6 + BIAS_DIM) [de/dxi, de/db]."""
        m = self.dim
        ncols = 6 if b is None else 6 + BIAS_DIM
        L, dL, valid = self.pairing.lines(E, self.axis, self.M, jacobian)
        if not valid:
            self.limb = -1
            return np.zeros(m), (np.zeros((m, ncols)) if jacobian else None)
        z = self.whitened(L)                                        # (m, 2)
        i = self.pairing.limbs(E, L)[self.slot]
        self.limb = i
        zi = z[:, i]
        if b is not None:
            zi = zi - (self.C @ limb_bias(b, i)) / self.sigma
        if not jacobian:
            return self.sqrt_w * self.kernel.apply_scalar(zi, None)[0], None
        J = np.zeros((m, ncols))
        # with the unbiased distance sigma z[:, i]: the bias term does not depend on E
        J[:, :6] = pixel_residual_jacobian(self.h, L[i], dL[i], self.sigma * z[:, i]) / self.sigma
        if b is not None:
            J[:, 6:] = (self.C @ limb_bias_jacobian(i)) / -self.sigma
        e, J = self.kernel.apply_scalar(zi, J)
        return (e, J) if self.sqrt_w == 1.0 else (self.sqrt_w * e, self.sqrt_w * J)

    @property
    def on_bias(self) -> bool:
        return self.C is not None



def shaft_pixels_factor(key: int, pixels: np.ndarray, axis: ShaftAxis, K: np.ndarray,
                        sigma: float, kernel: RobustKernel | str | None,
                        pairing: LimbPairing | None = None, weight: float = 1.0,
                        bias_key: int | None = None, direction: np.ndarray | None = None,
                        extrinsic: np.ndarray | None = None):
    """gtsam.CustomFactor on Pose3 ``key`` for one edge's pixels (m, 2); None if empty.
    ``extrinsic``: the observing camera from the left (stereo right: right_T_left,
    with K the right camera's), :mod:`factors.error_function`.
    With ``bias_key`` (the frame's edge-bias vector) the factor is on (key, bias_key);
    ``direction``: the frame's reference direction of the shaft for the slope terms.

    ``pairing``: the frame's :class:`LimbPairing` (shared by its edges' factors),
    None for the nearer-limb assignment of a lone set; ``weight``: the tempering
    w of the set's cost (module docstring). The noise model is unit
    (whitening and the per-pixel robust kernel happen inside the error function)."""
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    if len(pixels) == 0:
        return None
    fn = ShaftPixelsError(pixels, axis, K, sigma, kernel, pairing, weight, bias=bias_key is not None,
                          direction=direction)
    fn.extrinsic = None if extrinsic is None else np.asarray(extrinsic, float)
    keys = [key] if bias_key is None else [key, bias_key]
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(pixels)), keys, fn)
