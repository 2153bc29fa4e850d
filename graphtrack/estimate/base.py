"""The one streaming interface every estimator implements.

A :class:`Frame` is what a recording yields (raw image + joint readings); the
tracking loop (:mod:`graphtrack.track`) undistorts, detects and builds an
:class:`~graphtrack.detect.base.Observation`, then asks the estimator for the
lumped error E_t:

    est = estimator.step(frame, observation)     # -> Estimate

Estimators never see ground truth (truth.csv, labels.csv).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: trajectory.csv columns of an estimator's uncertainty: the standard deviations of
#: the LEFT camera-frame correction E = Exp(xi) . E_hat, xi = (b [m], w [rad]).
STD_COLUMNS = ("std_bx", "std_by", "std_bz", "std_wx", "std_wy", "std_wz")


@dataclass
class Frame:
    """One synchronised frame of a recording.

    index: 0-based frame number (bag order); stamp: seconds;
    image: raw (distorted) left image, H x W x 3 uint8 BGR (None if not decoded);
    joints: the DH joints' readings q~ (n,) in rad / m; jaw: jaw opening (rad),
    NaN when the tool has no gripper; image_right: the raw right image matched
    to this frame by stamp (stereo recordings), None when the recording is mono
    or this frame's right image is missing or corrupt.
    """

    index: int
    stamp: float
    image: np.ndarray | None
    joints: np.ndarray
    jaw: float = float("nan")
    image_right: np.ndarray | None = None

    @property
    def q(self) -> np.ndarray:
        """The full joint vector the kinematics takes: DH joints, then jaw if finite."""
        if np.isfinite(self.jaw):
            return np.concatenate([self.joints, [self.jaw]])
        return np.asarray(self.joints, dtype=float)


def monotone_stamp(stamp, previous: float | None, fps: float) -> float:
    """The seconds an estimator files a frame under: its stamp, or (no finite stamp)
    ``previous`` + 1 / fps (0 for the first frame); kept strictly increasing
    (``previous`` + 1 us), so time steps and fixed-lag windows never run backwards."""
    s = float(stamp) if stamp is not None else float("nan")
    if not np.isfinite(s):
        s = 0.0 if previous is None else previous + 1.0 / fps
    if previous is not None and s <= previous:
        s = previous + 1e-6
    return s


@dataclass
class Estimate:
    """The estimator's answer for one frame.

    E: 4x4 camera-from-base lumped-error transform (metres).
    std: six standard deviations of the correction (b in m, w in rad) in the
    estimator's own tangent space, or None when it has no uncertainty.
    cov: the 6x6 covariance behind ``std`` (optional).
    extra: further per-frame columns the estimator wants in trajectory.csv.
    """

    E: np.ndarray
    std: np.ndarray | None = None
    cov: np.ndarray | None = None
    extra: dict[str, float] = field(default_factory=dict)


class Estimator(Protocol):
    """Streaming estimator of E_t. ``name`` is used in outputs and studies."""

    name: str

    def step(self, frame: Frame, observation) -> Estimate:  # pragma: no cover - protocol
        """Consume one frame and its observation (may be empty); return E_t."""
        ...

    def finish(self) -> list[Estimate] | None:  # pragma: no cover - protocol
        """Called after the last frame. Offline estimators return the refined
        estimates for every frame (which then replace the streamed rows);
        online ones return None."""
        ...
