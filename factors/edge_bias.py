"""The detector's edge bias: a slowly varying state per projected limb and the shaft's end.

A line detector errs by the whole edge, by nearly the same amount from frame to
frame (why this is a state, with measurements: docs/decisions/edge-bias-state.md),
and an end detector by the same amount along the shaft (docs/decisions/end-offset-state.md;
the end is on the state in stereo frames only).
Each frame k carries, next to E_k, the bias vector (px)

    b_k = (l, l_s, w, w_s, e)

lateral offset l and slope l_s (both edges shifted the same way in the image) and
width offset w and slope w_s (both moved the same way relative to the shaft: a
depth or depth-tilt error). A pixel p of an edge set assigned to limb i has the residual

    R(p | theta_i(E), rho_i(E)) - c(p) . (w + sgn_i l, w_s + sgn_i l_s),   c(p) = (1, t(p) / T)

with t(p) (px) p's coordinate from the set's centroid along its principal direction,
oriented along the frame's reference direction of the shaft (:func:`reference_direction`:
robot.json's shaft axis projected through the fixed hand-eye prior E_0, the same for
both sets and all frames), and T = ``SLOPE_SCALE`` = 100 px: an offset at the
centroid, a slope per 100 px of edge. R is the signed distance to limb i's line
(A, B, C)(E) as :func:`graphtrack.geometry.cylinder.limb_line_coefficients` orients
it, both normals into the shaft's image: a lateral shift is +l on limb 0 and -l on
limb 1 (sgn = +1, -1); w > 0 moves both edges inwards (a narrower image).
The end offset e (px along the shaft's image, towards the wrist) is where the
detected shaft end lies from the modelled one (:mod:`factors.shaft_end`).

Over time b is a first-order Gauss-Markov process with stationary standard
deviations sigma = (sigma_l, sigma_ls, sigma_w, sigma_ws, sigma_e) and time constant tau:

    b_0 ~ N(0, diag(sigma^2)),
    b_k = phi b_{k-1} + w_k,  phi = exp(-dt / tau),  w_k ~ N(0, (1 - phi^2) diag(sigma^2))

(dt: seconds between the frames; the estimators may share one b among n
consecutive frames, ``edge_bias_every``, and step the chain every n frames):
the prior :func:`bias_prior_factor` and the transition :func:`bias_transition_factor`,
a linear factor with residual (b_k - phi b_{k-1}) / (sigma sqrt(1 - phi^2)) and
constant Jacobians.
"""
from __future__ import annotations

import gtsam
import numpy as np

#: the bias vector's dimension: (lateral offset, lateral slope, width offset, width slope, end offset)
BIAS_DIM = 5
#: the index of the shaft end's offset e in the bias vector
END_OFFSET = 4
#: sgn_i of the lateral terms on limb i
LATERAL_SIGN = (1.0, -1.0)
#: px of edge over which the slope s_i is the offset change
SLOPE_SCALE = 100.0


def bias_key(k: int) -> int:
    """The gtsam key of frame k's bias vector (symbol 'b', k)."""
    return gtsam.symbol("b", int(k))


def bias_sigmas(lateral: float, lateral_slope: float, width: float, width_slope: float,
                end: float) -> np.ndarray:
    """The stationary standard deviations (5,) of b = (l, l_s, w, w_s, e), px."""
    return np.array([lateral, lateral_slope, width, width_slope, end], float)


def reference_direction(E_ref: np.ndarray, p0: np.ndarray, d: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """Image direction (2,) of the shaft axis (base-frame point p0 and unit direction d,
    m) projected through the 4x4 E_ref with K; None when it does not project (behind
    the camera, end-on)."""
    P = np.stack([p0, p0 + 0.01 * np.asarray(d, float)]) @ E_ref[:3, :3].T + E_ref[:3, 3]
    if np.any(P[:, 2] <= 1e-6):
        return None
    uv = P[:, :2] / P[:, 2:] * np.array([K[0, 0], K[1, 1]])
    v = uv[1] - uv[0]
    n = float(np.hypot(*v))
    return None if n < 1e-9 else v / n


def bias_coefficients(pixels: np.ndarray, direction: np.ndarray | None = None) -> np.ndarray:
    """(m, 2): c(p) = (1, t(p) / T) for each pixel of one edge set: t along the set's
    principal direction from its centroid (px), oriented along ``direction`` (2,)
    (the frame's :func:`reference_direction`; without one: +y, +x if horizontal)."""
    p = np.asarray(pixels, float).reshape(-1, 2)
    if len(p) == 0:
        return np.zeros((0, 2))
    X = p - p.mean(axis=0)
    _, vecs = np.linalg.eigh(X.T @ X)
    u = vecs[:, 1]
    ref = np.array([1e-9, 1.0]) if direction is None else np.asarray(direction, float)
    if u @ ref < 0:
        u = -u
    return np.stack([np.ones(len(p)), (X @ u) / SLOPE_SCALE], axis=1)


def limb_bias(b: np.ndarray, limb: int) -> np.ndarray:
    """(offset, slope) (2,) of limb ``limb``'s edge for b = (l, l_s, w, w_s, e)."""
    b = np.asarray(b, float)
    return b[2:4] + LATERAL_SIGN[limb] * b[0:2]


def limb_bias_jacobian(limb: int) -> np.ndarray:
    """d(offset, slope)/db (2, 5) of :func:`limb_bias`."""
    g = LATERAL_SIGN[limb]
    return np.array([[g, 0.0, 1.0, 0.0, 0.0], [0.0, g, 0.0, 1.0, 0.0]])


def bias_prior_factor(k: int, sigmas: np.ndarray):
    """b_k ~ N(0, diag(sigmas^2)): the bias of the first frame."""
    return gtsam.PriorFactorVector(bias_key(k), np.zeros(BIAS_DIM),
                                   gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float)))


def transition(dt: float, tau: float) -> float:
    """phi = exp(-dt / tau) (dt, tau in seconds): tau = inf gives phi = 1, a bias
    that stays constant (the transition's step spread is floored at 1e-3 sigma);
    tau <= 0 gives phi = 0, an independent bias in every frame."""
    if tau <= 0:
        return 0.0
    if not np.isfinite(tau):
        return 1.0
    return float(np.exp(-max(float(dt), 0.0) / float(tau)))


class BiasTransitionError:
    """CustomFactor callback of b_k = phi b_{k-1} + w (keys b_{k-1}, b_k):

        e = (b_k - phi b_{k-1}) / q,   q = sigma sqrt(1 - phi^2)
        de/db_{k-1} = -phi diag(1/q),  de/db_k = diag(1/q)
    """

    def __init__(self, phi: float, sigmas: np.ndarray):
        self.phi = float(phi)
        sigmas = np.asarray(sigmas, float)
        # phi = 1 (a constant bias) keeps a small step instead of a zero one
        q = sigmas * np.sqrt(max(1.0 - self.phi ** 2, 1e-6))
        self.inv_q = 1.0 / q
        self.J_prev = -self.phi * np.diag(self.inv_q)
        self.J_next = np.diag(self.inv_q)

    def evaluate(self, b_prev: np.ndarray, b_next: np.ndarray) -> np.ndarray:
        return (np.asarray(b_next, float) - self.phi * np.asarray(b_prev, float)) * self.inv_q

    def __call__(self, this, values, H):
        keys = this.keys()
        e = self.evaluate(values.atVector(keys[0]), values.atVector(keys[1]))
        if H is not None:
            H[0] = self.J_prev
            H[1] = self.J_next
        return e


def bias_transition_factor(k_prev: int, k: int, phi: float, sigmas: np.ndarray):
    """gtsam.CustomFactor tying b_k to b_{k_prev} (see :class:`BiasTransitionError`)."""
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(BIAS_DIM), [bias_key(k_prev), bias_key(k)],
                              BiasTransitionError(phi, sigmas))
