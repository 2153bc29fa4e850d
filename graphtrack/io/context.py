"""What a recording gives every estimator: the robot, the left camera and the hand-eye prior."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphtrack.geometry.camera import Camera
from graphtrack.robot.description import RobotDescription


@dataclass
class TrackingContext:
    """robot: the kinematic chain and features; camera: the LEFT camera (undistorted
    pixels share its K); handeye: the nominal camera-from-base E_0 (4x4, metres),
    the prior every estimator starts from."""

    robot: RobotDescription
    camera: Camera
    handeye: np.ndarray
