"""Point-to-projected-line factor: one shaft edge's pixel set against E.

For the edge's pixels p_j = (x_j, y_j), j = 1..m (undistorted px), and the
projected limb line (theta(E), rho(E)) of the shaft axis (fixed base-frame
data of the frame's readings) the residual vector is

    z_j = R(p_j | theta(E), rho(E)) / sigma
        = (cos theta x_j + sin theta y_j - rho) / sigma
        = (A x_j + B y_j + C) / (|(A, B)| sigma),     (A, B, C) = L(E)

(the method's pixel residual, signed distance in px), robustified per pixel
(:mod:`factors.robust`). ONE factor per edge carries all its pixels
(vectorised), so GTSAM makes one Python callback per edge and frame.

Analytic Jacobian (right perturbation xi = (omega, v)): with h_j = (x_j, y_j, 1),
s = |(A, B)| and dL/dxi from :func:`factors.limb.limb_lines`,

    dz_j/dxi = (h_j - z_j sigma (A, B, 0)/s) / (s sigma) . dL/dxi

Edge assignment: the factor compares its pixels with BOTH projected limbs and
uses the limb with the smaller robust cost, re-deciding at every evaluation
(so each relinearisation re-assigns the pixel set to the nearer projected
edge; the cost is the minimum over the two assignments, continuous in E).
A degenerate view (``valid`` False) gives a zero residual and zero Jacobian:
the factor then says nothing and the graph stays solvable.
"""
from __future__ import annotations

import numpy as np

from factors.limb import ShaftAxis, limb_lines, line_matrix
from factors.error_function import PoseErrorFunction
from factors.robust import RobustKernel, make_kernel


class ShaftPixelsError(PoseErrorFunction):
    """Typed error function of one edge's pixel set (call it like GTSAM does)."""

    def __init__(self, pixels: np.ndarray, axis: ShaftAxis, K: np.ndarray, sigma: float = 1.5,
                 kernel: RobustKernel | str | None = "cauchy"):
        self.pixels = np.asarray(pixels, float).reshape(-1, 2)
        self.h = np.hstack([self.pixels, np.ones((len(self.pixels), 1))])  # (m, 3)
        self.axis = axis
        self.M = line_matrix(np.asarray(K, float))
        self.sigma = float(sigma)
        self.kernel = make_kernel(kernel)
        self.limb = -1      # limb used at the last evaluation (0 / 1), -1: degenerate

    @property
    def dim(self) -> int:
        return len(self.pixels)

    def evaluate(self, E: np.ndarray, jacobian: bool = True):
        """Residual e (m,) and de/dxi (m, 6) (None without ``jacobian``) at 4x4 E."""
        m = self.dim
        L, dL, valid = limb_lines(E, self.axis, self.M, jacobian)
        if not valid:
            self.limb = -1
            return np.zeros(m), (np.zeros((m, 6)) if jacobian else None)
        s = np.hypot(L[:, 0], L[:, 1])                              # (2,)
        z = (self.h @ L.T) / (s * self.sigma)                       # (m, 2)
        cost = self.kernel.loss(np.abs(z)).sum(axis=0)
        i = int(np.argmin(cost))
        self.limb = i
        zi = z[:, i]
        if not jacobian:
            return self.kernel.apply_scalar(zi, None)[0], None
        ab0 = np.array([L[i, 0], L[i, 1], 0.0]) / s[i]
        # dz/dxi = (h - z sigma (A, B, 0)/s)/(s sigma) . dL/dxi, evaluated as h.(dL/s sigma) - z (ab0.dL/s)
        dLi = dL[i] / (s[i] * self.sigma)                            # (3, 6)
        J = self.h @ dLi - zi[:, None] * (self.sigma * (ab0 @ dLi))[None, :]
        return self.kernel.apply_scalar(zi, J)



def shaft_pixels_factor(key: int, pixels: np.ndarray, axis: ShaftAxis, K: np.ndarray,
                        sigma: float = 1.5, kernel: RobustKernel | str | None = "cauchy"):
    """gtsam.CustomFactor on Pose3 ``key`` for one edge's pixels (m, 2); None if empty.

    The noise model is unit (whitening and the per-pixel robust kernel happen
    inside the error function)."""
    import gtsam

    pixels = np.asarray(pixels, float).reshape(-1, 2)
    if len(pixels) == 0:
        return None
    fn = ShaftPixelsError(pixels, axis, K, sigma, kernel)
    f = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(pixels)), [key], fn)
    return f
