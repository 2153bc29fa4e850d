"""What a recording gives every estimator: the robot, the left camera, the hand-eye prior
and, for a stereo recording tracked in stereo, the right camera and the rig's extrinsics."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.geometry.camera import Camera
from graphtrack.robot.description import RobotDescription


@dataclass
class TrackingContext:
    """robot: the kinematic chain and features; camera: the LEFT camera (undistorted
    pixels share its K); handeye: the nominal camera-from-base E_0 (4x4, metres),
    the prior every estimator starts from.

    right: the RIGHT camera (undistorted right pixels share its K2), None when mono
    (a mono recording, or ``--mono``); right_T_left: 4x4 right-from-left transform
    (metres), so the right camera's camera-from-base pose is right_T_left . E."""

    robot: RobotDescription
    camera: Camera
    handeye: np.ndarray
    right: Camera | None = None
    right_T_left: np.ndarray | None = None

    @classmethod
    def of(cls, rec, stereo: bool = True) -> TrackingContext:
        """The context of an open recording (:func:`graphtrack.io.recording.open_recording`):
        stereo when the recording is (right images and K2, D2, R, T) and ``stereo``, else
        the left camera alone."""
        cal = rec.calibration
        if stereo and rec.stereo:
            return cls(rec.robot, cal.left, rec.handeye, cal.right, cal.right_T_left)
        return cls(rec.robot, cal.left, rec.handeye)

    @property
    def stereo(self) -> bool:
        """Whether estimators get right-image observations (a right camera and its extrinsics)."""
        return self.right is not None and self.right_T_left is not None
