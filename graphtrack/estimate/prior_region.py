"""The hand-eye prior's region: where the lumped error E can lie.

With x = (b [m], w [rad]) the left perturbation of E = Exp(x) . E_ref from the prior's
centre E_ref (the recording's hand-eye calibration) and sigma = (sigma_b x 3, sigma_w x 3)
the prior's spread, the region is |x / sigma|^2 <= ``PRIOR_GATE``, chi^2 with 6 degrees
of freedom at 99.9 %. An estimate outside it has run away (the re-initialisation
policy's prior guard, the smoother's containment, the batch's left-out frames).

A whole run's correction (:func:`correction`, the median over its frames) beyond
``PRIOR_HINT`` (chi^2_6 at 99 %) says that the calibration is off by more than the prior
allows for: the tracker warns and names ``--handeye-sigma``
(docs/decisions/handeye-sigma.md).
"""
from __future__ import annotations

import numpy as np

from graphtrack.geometry.se3 import invert, matrix_to_bw

#: chi^2 with 6 degrees of freedom, 99.9 % point: the hand-eye prior's extent
PRIOR_GATE = 22.46
#: chi^2 with 6 degrees of freedom, 99 % point: a run's median correction beyond it
#: suggests a wider prior (:func:`correction`)
PRIOR_HINT = 16.81


def prior_distance(E: np.ndarray, E_ref: np.ndarray, sigma_b: float, sigma_w: float) -> float:
    """|x / sigma|^2 of E = Exp(x) . E_ref, x = (b [m], w [rad]) the left perturbation,
    sigma = (sigma_b [m] x 3, sigma_w [rad] x 3): the squared Mahalanobis distance from the prior."""
    x = matrix_to_bw(np.asarray(E, float) @ invert(np.asarray(E_ref, float)))
    return float(_scaled_sq(x, sigma_b, sigma_w))


def _scaled_sq(x: np.ndarray, sigma_b: float, sigma_w: float) -> np.ndarray:
    """|x / sigma|^2 over the last axis of x (..., 6), sigma = (sigma_b x 3, sigma_w x 3)."""
    return np.sum((np.asarray(x, float) / np.repeat([sigma_b, sigma_w], 3)) ** 2, axis=-1)


def outside_prior(E: np.ndarray, E_ref: np.ndarray, sigma_b: float, sigma_w: float,
                  gate: float = PRIOR_GATE) -> bool:
    """True when E lies outside the prior's region :func:`prior_distance` <= gate."""
    return prior_distance(E, E_ref, sigma_b, sigma_w) > gate


def correction(Es, E_ref: np.ndarray, sigma_b: float, sigma_w: float) -> dict:
    """The correction a run applied to its hand-eye calibration E_ref, over the estimates
    ``Es`` (4x4 each): medians over the frames of |b| (mm), |w| (deg) and
    :func:`prior_distance` at (sigma_b m, sigma_w rad); ``frames``: how many. Empty without frames."""
    Es = [np.asarray(E, float) for E in Es]
    if not Es:
        return {}
    inv = invert(np.asarray(E_ref, float))
    x = np.array([matrix_to_bw(E @ inv) for E in Es])
    d = _scaled_sq(x, sigma_b, sigma_w)
    return {"b_mm": float(np.median(np.linalg.norm(x[:, :3], axis=1)) * 1e3),
            "w_deg": float(np.degrees(np.median(np.linalg.norm(x[:, 3:], axis=1)))),
            "prior_distance": float(np.median(d)), "frames": len(Es)}
