"""Forward kinematics of a modified-DH chain with the two gripper links, vectorised.

    base_T_link_k = T_1(q_1) T_2(q_2) ... T_k(q_k),
    T_i = RotX(alpha_i) TransX(A_i) RotZ(theta_i) TransZ(D_i)      (metres, radians)

and, with a gripper (jaw angle j = q[n]),

    base_T_link_{n+1} = base_T_link_n RotZ(+j/2),   base_T_link_{n+2} = base_T_link_n RotZ(-j/2).

Every function takes joint vectors q of shape (..., n_joints) and loops only
over the (few) joints, never over the leading axes.
"""
from __future__ import annotations

import math

import numpy as np

from graphtrack.errors import InputError
from graphtrack.geometry.se3 import rot_x, rot_z, trans
from graphtrack.robot.description import RobotDescription


def check_joints(robot: RobotDescription, q: np.ndarray, where: str = "joints") -> np.ndarray:
    """Return q as float array, raising InputError on a wrong length or NaN."""
    q = np.asarray(q, dtype=float)
    if q.shape[-1] != robot.n_joints:
        raise InputError(f"{where}: expected {robot.n_joints} joint values "
                         f"({robot.n_dh} DH joints{' + jaw' if robot.has_gripper else ''}), got {q.shape[-1]}")
    if not np.all(np.isfinite(q)):
        raise InputError(f"{where}: NaN or infinite joint reading")
    return q


def joint_transform(joint, qi: np.ndarray) -> np.ndarray:
    """T_i(q_i) = RotX(alpha) TransX(A) RotZ(theta) TransZ(D) (modified DH) for one DHJoint, qi
    (rad for a revolute joint, m for a prismatic one) of any shape -> (..., 4, 4), metres."""
    qi = np.asarray(qi, dtype=float)
    if joint.type == "revolute":
        theta, D = joint.theta + joint.offset + qi, np.full(qi.shape, joint.D)
    else:
        theta, D = np.full(qi.shape, joint.theta), joint.D + joint.offset + qi
    fixed = rot_x(joint.alpha) @ trans(joint.A)
    return fixed @ rot_z(theta) @ trans(0.0, 0.0, D)


def link_transforms(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """base_T_link for links 0..n_links: (..., n_links + 1, 4, 4), metres; link 0 is the base.
    q (..., n_joints): the DH joints (rad / m), then the jaw (rad) for a tool with a gripper."""
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        return _single_link_transforms(robot, q)
    lead = q.shape[:-1]
    out = np.empty(lead + (robot.n_links + 1, 4, 4))
    T = np.broadcast_to(np.eye(4), lead + (4, 4)).copy()
    out[..., 0, :, :] = T
    for i, joint in enumerate(robot.dh):
        T = T @ joint_transform(joint, q[..., i])
        out[..., i + 1, :, :] = T
    if robot.has_gripper:
        j = q[..., robot.n_dh]
        out[..., robot.n_dh + 1, :, :] = T @ rot_z(j / 2.0)
        out[..., robot.n_dh + 2, :, :] = T @ rot_z(-j / 2.0)
    return out


def dh_matrix(alpha: float, A: float, theta: float, D: float) -> np.ndarray:
    """RotX(alpha) TransX(A) RotZ(theta) TransZ(D) multiplied out (one joint, scalars)::

        [[ ct,     -st,      0,   A      ],
         [ st ca,   ct ca,  -sa, -sa D   ],
         [ st sa,   ct sa,   ca,  ca D   ],
         [ 0,       0,       0,   1      ]]
    """
    ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
    return np.array([[ct, -st, 0.0, A], [st * ca, ct * ca, -sa, -sa * D],
                     [st * sa, ct * sa, ca, ca * D], [0.0, 0.0, 0.0, 1.0]])


def _single_link_transforms(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """:func:`link_transforms` for ONE joint vector (n_joints,), with the closed-form
    joint matrices (the particle filter calls this once per frame: ~10x fewer numpy calls)."""
    out = np.empty((robot.n_links + 1, 4, 4))
    T = np.eye(4)
    out[0] = T
    for i, j in enumerate(robot.dh):
        qi = float(q[i])
        if j.type == "revolute":
            Ti = dh_matrix(j.alpha, j.A, j.theta + j.offset + qi, j.D)
        else:
            Ti = dh_matrix(j.alpha, j.A, j.theta, j.D + j.offset + qi)
        T = T @ Ti
        out[i + 1] = T
    if robot.has_gripper:
        h = 0.5 * float(q[robot.n_dh])
        out[robot.n_dh + 1] = T @ dh_matrix(0.0, 0.0, h, 0.0)
        out[robot.n_dh + 2] = T @ dh_matrix(0.0, 0.0, -h, 0.0)
    return out
