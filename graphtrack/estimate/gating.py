"""Association gates that follow the estimate's covariance: the markers', and the shaft
end's along the shaft (:func:`gate_along`).

A marker point X (camera frame, at the current estimate E_t) moves under a left
correction (b, w) of E as dX = b + w x X = A(X) (b, w), A = [I, -[X]x]; its
projection moves by J(X) dX, J the pinhole Jacobian (:mod:`graphtrack.geometry.pinhole`)
[[f_x / z, 0, -f_x x / z^2], [0, f_y / z, -f_y y / z^2]]. With C (6x6) the
covariance of (b, w) (m, rad; the estimators' ``Estimate.cov``), the predicted
marker's image covariance is P = J A C A^T J^T (px^2). The gate (px) is

    g = n_sigma * sqrt(lambda_max(P) + sigma^2)

maximised over the markers in front of the camera (one gate per frame, as the
association takes), with sigma (px) the detections' own noise, and by default
clipped to [configured gate, ``ceil``]: it widens with the estimate's uncertainty (a
long gap, a re-initialisation, a wide particle cloud) and returns to the configured
gate as the estimate becomes confident, not below it (a wrong lock's covariance is
over-confident). Without a usable covariance (None, non-finite) the configured gate
is kept.

The smoother's gate (:func:`smoother_gate`, on by default: its
``marker_gate_follows_covariance``) is g with n_sigma = 3.72 (chi^2_2's 99.9 % point: a
consistent detection is gated out once in a thousand), at most the configured gate (so
at least 3.72 sigma = 7.4 px): the configured gate while the window starts (no covariance yet),
narrow once the estimate is confident, so that a blob far from every marker (a
highlight, a coloured patch of tissue) is not paired with a marker the detector missed,
whose robust residual would pull the estimate by a constant 1.345 sigma every frame.
The particle filter's (off by default) widens only: its gate is the cap of the robust
marker cost, part of its tuned likelihood. Measurements: docs/decisions/marker-gate.md,
startup-search.md.
"""
from __future__ import annotations

import numpy as np

from graphtrack.geometry import pinhole

N_SIGMA = 3.0          #: gate half-width in standard deviations of the predicted marker
CEIL_PX = 150.0        #: widest gate (detection pixels)
#: the smoother's gate in sigmas: a 2-D residual's chi^2_2 99.9 % point, sqrt(-2 ln 0.001)
N_SIGMA_2D = float(np.sqrt(-2.0 * np.log(1e-3)))


def marker_image_covariances(points: np.ndarray, K: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """P_i (M, 2, 2) px^2 of camera-frame points (M, 3) m under a left (b, w) covariance cov (6, 6);
    NaN for a point behind the camera."""
    X = np.asarray(points, float).reshape(-1, 3)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    J = pinhole.jacobian(K, X)              # NaN for a point behind the camera
    A = np.zeros((len(X), 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, 0, 4], A[:, 0, 5] = z, -y        # -[X]x: w x X = (w_y z - w_z y, w_z x - w_x z, w_x y - w_y x)
    A[:, 1, 3], A[:, 1, 5] = -z, x
    A[:, 2, 3], A[:, 2, 4] = y, -x
    G = J @ A                               # (M, 2, 6)
    return G @ np.asarray(cov, float) @ np.swapaxes(G, 1, 2)


def marker_gate(points: np.ndarray, K: np.ndarray, cov: np.ndarray | None, gate: float,
                sigma: float, scale: float = 1.0, n_sigma: float = N_SIGMA,
                floor: float | None = None, ceil: float = CEIL_PX) -> float:
    """The gate (px, full size) of the module doc.

    points (M, 3): marker points in the camera frame at the current estimate (m);
    K: intrinsics (full-size px); cov: (6, 6) left (b, w) covariance or None;
    gate: the configured gate (full-size px), returned when cov is unusable or no
    marker is in front of the camera; sigma: detection noise (px); scale: full-size
    pixels per detection pixel; floor (default: the configured gate) and ceil in
    detection pixels.
    """
    X = np.asarray(points, float).reshape(-1, 3)
    X = X[np.all(np.isfinite(X), axis=1) & (X[:, 2] > 1e-3)] if len(X) else X
    if cov is None or len(X) == 0 or not np.all(np.isfinite(cov)):
        return float(gate)
    P = marker_image_covariances(X, K, cov)
    a, d, b = P[:, 0, 0], P[:, 1, 1], 0.5 * (P[:, 0, 1] + P[:, 1, 0])
    lam = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b * b)   # the larger eigenvalue of [[a, b], [b, d]]
    g = n_sigma * np.sqrt(np.max(np.clip(lam, 0.0, None)) + sigma ** 2)
    lo = float(gate) if floor is None else floor * scale
    return float(np.clip(g, lo, max(lo, ceil * scale)))


def smoother_gate(points: np.ndarray, K: np.ndarray, cov: np.ndarray | None, opts) -> float:
    """The smoother's marker gate (detection px): :func:`marker_gate` at ``N_SIGMA_2D`` with
    no floor but its own N_SIGMA_2D * marker_sigma, at most the configured gate; points:
    the markers in the camera frame (m); opts: its FactorOptions (marker_gate, marker_sigma,
    gate_scale)."""
    g = marker_gate(points, K, cov, opts.marker_gate * opts.gate_scale, opts.marker_sigma, opts.gate_scale,
                    n_sigma=N_SIGMA_2D, floor=0.0, ceil=opts.marker_gate)
    return g / opts.gate_scale


def gate_along(point: np.ndarray, direction: np.ndarray, K: np.ndarray, cov: np.ndarray, sigma: float,
               floor: float, n_sigma: float = N_SIGMA) -> float:
    """The gate (px) along a unit image direction d of a camera-frame point's (3,) projection:
    max(floor, n_sigma sqrt(d^T P d + sigma^2)), P its image covariance under the left (b, w)
    covariance ``cov`` (:func:`marker_image_covariances`), sigma (px) the detection's own
    noise along d; inf for a point behind the camera (no image covariance). The shaft end's
    gate: only its position along the shaft is scored."""
    P = marker_image_covariances(np.asarray(point, float)[None], K, cov)[0]
    if not np.all(np.isfinite(P)):
        return float("inf")
    d = np.asarray(direction, float)
    return max(float(floor), n_sigma * float(np.sqrt(max(d @ P @ d, 0.0) + sigma * sigma)))
