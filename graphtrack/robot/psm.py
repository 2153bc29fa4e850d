"""The dVRK patient-side manipulator with a Large Needle Driver (400006).

Public modified-DH values of the classic dVRK PSM (the arm's joints 1-3: outer
yaw, outer pitch, insertion; the tool's joints 4-6: roll, wrist pitch, wrist
yaw) and the tool's visible geometry. The simulator renders exactly these
numbers and writes them to robot.json, so tracking and rendering share one
model.

Frames: link 4 (after the roll) sits on the wrist-pitch axis with z along the
insertion shaft, pointing from the remote centre of motion towards the tip;
link 6 is the wrist-yaw frame; the jaws (links 7, 8) extend along +y of their
frames for JAW_LENGTH.
"""
from __future__ import annotations

import numpy as np

from graphtrack.robot.description import (DHJoint, PointFeature, RobotDescription, ShaftFeature,
                                           SkeletonSegment)

HALF_PI = np.pi / 2
RCC_LENGTH = 0.4318       # m, remote centre to the insertion reference (joint 3 offset)
TOOL_LENGTH = 0.4162      # m, tool main shaft length (joint 4 D)
PITCH_TO_YAW = 0.0091     # m, wrist pitch axis to yaw axis
JAW_LENGTH = 0.0102       # m, yaw axis to the jaw tip
SHAFT_RADIUS = 0.004      # m, 8 mm shaft
SHAFT_END = -0.004        # m, where the shaft cylinder ends on link 4's z (the wrist begins)
MARKER_RADIUS = 0.0011    # m, painted disc radius on the shaft surface

PSM_DH = [
    DHJoint("revolute", HALF_PI, 0.0, 0.0, 0.0, HALF_PI),           # 1 outer yaw
    DHJoint("revolute", -HALF_PI, 0.0, 0.0, 0.0, -HALF_PI),         # 2 outer pitch
    DHJoint("prismatic", HALF_PI, 0.0, 0.0, 0.0, -RCC_LENGTH),      # 3 insertion
    DHJoint("revolute", 0.0, 0.0, 0.0, TOOL_LENGTH, 0.0),           # 4 roll
    DHJoint("revolute", -HALF_PI, 0.0, 0.0, 0.0, -HALF_PI),         # 5 wrist pitch
    DHJoint("revolute", -HALF_PI, PITCH_TO_YAW, 0.0, 0.0, -HALF_PI),  # 6 wrist yaw
]

#: Painted blue markers on the shaft near the wrist (link 4): (angle about the
#: shaft axis, z along it), on the surface of the cylinder; discs of MARKER_RADIUS.
MARKER_LAYOUT = [(0.0, -0.010), (np.pi / 2, -0.016), (np.pi, -0.010), (3 * np.pi / 2, -0.016)]

JOINT_LIMITS = np.array([[-1.6, 1.6], [-0.9, 0.9], [0.05, 0.24], [-4.5, 4.5],
                         [-1.4, 1.4], [-1.4, 1.4], [0.0, 1.0]])


def psm_large_needle_driver() -> RobotDescription:
    """The PSM + Large Needle Driver as a RobotDescription (robot.json content)."""
    markers = [PointFeature(f"marker_{i}", 4, (SHAFT_RADIUS * np.cos(a), SHAFT_RADIUS * np.sin(a), z),
                            MARKER_RADIUS)
               for i, (a, z) in enumerate(MARKER_LAYOUT)]
    shaft = ShaftFeature("shaft", 4, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), SHAFT_RADIUS, SHAFT_END)
    skeleton = [
        SkeletonSegment(4, (0.0, 0.0, -0.04), 4, (0.0, 0.0, SHAFT_END)),
        SkeletonSegment(4, (0.0, 0.0, SHAFT_END), 5, (0.0, 0.0, 0.0)),
        SkeletonSegment(5, (0.0, 0.0, 0.0), 6, (0.0, 0.0, 0.0)),
        SkeletonSegment(6, (0.0, 0.0, 0.0), 7, (0.0, JAW_LENGTH, 0.0)),
        SkeletonSegment(6, (0.0, 0.0, 0.0), 8, (0.0, JAW_LENGTH, 0.0)),
    ]
    tip = PointFeature("tool_tip", 7, (0.0, JAW_LENGTH, 0.0))
    return RobotDescription(list(PSM_DH), True, markers, [shaft], skeleton, tip, JOINT_LIMITS.copy())
