"""Plausible joint readings: radians and metres, not degrees or millimetres.

A revolute joint of a real arm never reads more than a full turn, |q| <= 2 pi rad
(the dVRK PSM's widest, the tool roll, stays within about 4.5 rad), and a
prismatic one never more than ``MAX_PRISMATIC_M`` (the PSM's insertion is under
0.3 m); the jaw is revolute. A reading beyond is a frame recorded in other units
(degrees, millimetres) or a damaged message. Without the robot's joint types the
loose bound ``MAX_JOINT`` applies to every reading.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError

#: rad: a revolute joint (or jaw) reading beyond a full turn
MAX_REVOLUTE_RAD = 2.0 * math.pi
#: m: a prismatic joint reading beyond this
MAX_PRISMATIC_M = 1.0
#: rad or m: any reading beyond this, when the joint types are not known
MAX_JOINT = 100.0


def joint_bounds(robot, n: int | None) -> np.ndarray | None:
    """(n,) |q| bounds of the DH joints from ``robot.dh``'s joint types; None when the robot
    description has no DH joints of that count (the loose bound applies)."""
    dh = getattr(robot, "dh", None)
    if not isinstance(dh, (list, tuple)) or n is None or len(dh) != n:
        return None
    return np.array([MAX_PRISMATIC_M if getattr(j, "type", "") == "prismatic" else MAX_REVOLUTE_RAD for j in dh])


def out_of_range(joints: np.ndarray, jaw: float, bounds: np.ndarray | None, has_jaw: bool) -> str | None:
    """Why a (finite) reading is not one of a real arm in radians and metres, naming the
    first joint beyond its bound; None when every joint (and the jaw) is within."""
    q = np.asarray(joints, float).ravel()
    loose = bounds is None or len(bounds) != q.size     # the joint types unknown: one loose bound
    b = np.full(q.size, MAX_JOINT) if loose else bounds
    if has_jaw:
        q, b = np.append(q, jaw), np.append(b, MAX_JOINT if loose else MAX_REVOLUTE_RAD)
    bad = np.flatnonzero(np.abs(q) > b)
    if not bad.size:
        return None
    i = int(bad[0])
    name = "jaw" if has_jaw and i == q.size - 1 else f"q{i + 1}"
    if loose:
        return f"{name} = {q[i]:.6g} is beyond |q| <= {MAX_JOINT:g} (rad or m)"
    if b[i] == MAX_REVOLUTE_RAD:
        return (f"{name} = {q[i]:.6g} is beyond a full turn (|q| <= {MAX_REVOLUTE_RAD:.4g} rad for a "
                "revolute joint): joint angles are radians (degrees?)")
    return (f"{name} = {q[i]:.6g} is beyond |q| <= {MAX_PRISMATIC_M:g} m for a prismatic joint: "
            "lengths are metres (millimetres?)")

def check_table(joints: np.ndarray, jaw: np.ndarray, bounds: np.ndarray | None, has_jaw: bool, path: Path | str,
                rows: str = "rows", item: str = "frame") -> None:
    """InputError naming ``path`` when most ``rows`` of a joint table (N, n) are beyond their
    bounds: a file in other units, not a few damaged rows (those are per-frame skips); the
    first such is named as ``item`` with its index."""
    if bounds is None or not len(joints) or np.shape(joints)[1] != len(bounds):
        return
    finite = np.all(np.isfinite(joints), axis=1)
    why = [out_of_range(q, a, bounds, has_jaw) if ok else None for q, a, ok in zip(joints, jaw, finite)]
    bad = [k for k, w in enumerate(why) if w is not None]
    if 2 * len(bad) > int(finite.sum()):
        raise InputError(f"{path}: {len(bad)} of {len(joints)} {rows} hold readings no arm makes in radians "
                         f"and metres (first: {item} {bad[0]}, {why[bad[0]]})")
