"""Robust kernels applied per residual group inside one factor.

Why not ``gtsam.noiseModel.Robust`` on the pixel / marker factors: GTSAM applies
a robust noise model to the WHOLE whitened error vector of a factor
(rho(||e||)), so on a factor that carries all 500 pixels of an edge one stray
pixel would down-weight every pixel of it. Here the kernel is applied to each
group separately (a pixel: group of 1; a marker: group of 2) with the same
loss as gtsam's ``noiseModel.mEstimator.Huber`` / ``Cauchy`` (tested equal):

    Huber(k):  rho(x) = x^2/2 (x <= k),  k x - k^2/2 (x > k)
    Cauchy(k): rho(x) = k^2/2 log(1 + x^2/k^2)

with x = ||z|| the whitened group norm. The factor returns, per group,

    e = g(x) z / x,   g(x) = sqrt(2 rho(x))

so that 0.5 ||e||^2 = rho(x) exactly (the cost LM / iSAM2 see is the robust
cost), and the Jacobian

    de/dz = (g/x) (I - z^ z^T) + g'(x) z^ z^T,   g' = psi(x)/g(x),  z^ = z/x

gives the exact gradient psi(x) z^T dz (a square-root / Triggs-style
reweighting; an inlier with x -> 0 keeps e = z and de/dz = I).
The small factors (one detected line: 2 residuals) use
``gtsam.noiseModel.Robust`` directly via :meth:`RobustKernel.gtsam_noise`.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

_TINY = 1e-9


@dataclass(frozen=True)
class RobustKernel:
    """kind: "huber" | "cauchy" | "none"; k: kernel width in whitened units (sigmas)."""

    kind: str = "cauchy"
    k: float = 2.0

    def loss(self, x: np.ndarray) -> np.ndarray:
        """rho(x) for whitened norms x >= 0."""
        x = np.abs(np.asarray(x, float))
        if self.kind == "huber":
            return np.where(x <= self.k, 0.5 * x * x, self.k * x - 0.5 * self.k * self.k)
        if self.kind == "cauchy":
            return 0.5 * self.k * self.k * np.log1p((x / self.k) ** 2)
        return 0.5 * x * x

    def psi(self, x: np.ndarray) -> np.ndarray:
        """rho'(x) (the influence function) for x >= 0."""
        x = np.abs(np.asarray(x, float))
        if self.kind == "huber":
            return np.minimum(x, self.k)
        if self.kind == "cauchy":
            return x / (1.0 + (x / self.k) ** 2)
        return x

    def apply_scalar(self, z: np.ndarray, J: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Groups of one: z (m,), J (m, 6): e = sign(z) g(|z|), de/dxi = g'(|z|) dz/dxi."""
        if self.kind == "none":
            return z, J
        x = np.abs(z)
        if self.kind == "huber":
            out = x > self.k
            if not out.any():
                return z, J
            xo = x[out]
            g = np.sqrt(2.0 * self.k * xo - self.k * self.k)
            e = z.copy()
            e[out] = np.sign(z[out]) * g
            if J is None:
                return e, None
            J = J.copy()
            J[out] *= (self.k / g)[:, None]
            return e, J
        g = np.sqrt(2.0 * self.loss(x))
        small = x < 1e-6
        a = np.where(small, 1.0, g / np.maximum(x, _TINY))
        e = a * z
        if J is None:
            return e, None
        gp = np.where(small, 1.0, self.psi(x) / np.maximum(g, _TINY))
        return e, gp[:, None] * J

    def apply(self, z: np.ndarray, J: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Robustify whitened groups z (N, g) with Jacobians J (N, g, 6) -> (e, de/dxi)."""
        z = np.asarray(z, float)
        if self.kind == "none":
            return z, J
        x = np.linalg.norm(z, axis=1)
        xs = np.maximum(x, _TINY)
        g = np.sqrt(2.0 * self.loss(x))
        small = x < 1e-6
        a = np.where(small, 1.0, g / xs)                           # g / x
        gp = np.where(small, 1.0, self.psi(x) / np.maximum(g, _TINY))  # g'
        e = a[:, None] * z
        if J is None:
            return e, None
        zh = z / xs[:, None]
        zJ = np.einsum("ng,ngk->nk", zh, J)                        # z^T J
        Jr = a[:, None, None] * J + ((gp - a)[:, None, None] * zh[:, :, None] * zJ[:, None, :])
        return e, Jr

    def gtsam_noise(self, base):
        """``gtsam.noiseModel.Robust`` around ``base`` (or base itself for "none")."""
        if self.kind == "none":
            return base
        est = {"huber": gtsam.noiseModel.mEstimator.Huber,
               "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[self.kind].Create(self.k)
        return gtsam.noiseModel.Robust.Create(est, base)


def make_kernel(kind: str | RobustKernel | None = "cauchy", k: float | None = None) -> RobustKernel:
    """Kernel from a name ("huber", "cauchy", "none"/None) and width k in sigmas (defaults:
    Huber 1.345, gtsam's; Cauchy 2.0). ValueError for another name."""
    if isinstance(kind, RobustKernel):
        return kind
    kind = "none" if kind in (None, "none", "gaussian", "l2") else str(kind).lower()
    if kind not in ("huber", "cauchy", "none"):
        raise ValueError(f"robust kernel {kind!r}: choose huber, cauchy or none")
    if k is None:
        k = {"huber": 1.345, "cauchy": 2.0, "none": 1.0}[kind]
    return RobustKernel(kind, float(k))
