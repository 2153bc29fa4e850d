"""One synchronised frame of a recording: what every recording source yields."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
