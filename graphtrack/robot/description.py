"""The arm and tool: robot.json (the sequence format) and the dVRK's own config files.

robot.json (docs/sequence-format.md) holds modified (Craig) DH
parameters, one entry per joint, and the features the camera sees. Joint i's
transform from frame i-1 to frame i is

    T_i = RotX(alpha) TransX(A) RotZ(theta_i) TransZ(D_i)
    revolute:  theta_i = theta + offset + q_i,  D_i = D
    prismatic: theta_i = theta,                 D_i = D + offset + q_i

Links are numbered from 1 (link k = frame after joint k). With a gripper the
joint vector carries the jaw angle j after the n DH joints and links n+1, n+2
are link n RotZ(+j/2) and link n RotZ(-j/2).

The dVRK's configuration files (an arm file and a tool file, JSON with
``// comments``, ``"DH": {"convention": "modified", "links"|"joints": [...]}``)
are a second source, combined into one chain by :func:`load_dvrk_config`.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphtrack.errors import InputError, is_number, read_json


@dataclass(frozen=True)
class DHJoint:
    """One modified-DH joint: angles in rad, lengths in m."""

    type: str  # "revolute" | "prismatic"
    alpha: float
    A: float
    theta: float
    D: float
    offset: float = 0.0


@dataclass(frozen=True)
class PointFeature:
    """A 3-D point (m) fixed to link ``link`` (a painted marker, the tool tip).

    ``radius`` (m, optional robot.json key, default 0): a painted marker's disc
    radius on the shaft surface, for the factor-graph estimators' centroid
    model (:mod:`graphtrack.geometry.painted_marker`); 0 is a point.
    """

    name: str
    link: int
    position: tuple[float, float, float]
    radius: float = 0.0


@dataclass(frozen=True)
class ShaftFeature:
    """A cylinder fixed to a link: point on the centre line, direction, radius (m).

    ``end`` (m, optional robot.json key): where the dark shaft ends on the wrist
    side, as the coordinate along ``direction`` (unit) from ``position``; None: not
    known, and the shaft's end is not observed (:mod:`graphtrack.detect.shaft_end`).
    """

    name: str
    link: int
    position: tuple[float, float, float]
    direction: tuple[float, float, float]
    radius: float
    end: float | None = None


@dataclass(frozen=True)
class SkeletonSegment:
    """A segment between a point on link1 and a point on link2, for drawing only."""

    link1: int
    position1: tuple[float, float, float]
    link2: int
    position2: tuple[float, float, float]


@dataclass
class RobotDescription:
    dh: list[DHJoint]
    has_gripper: bool = False
    point_features: list[PointFeature] = field(default_factory=list)
    shaft_features: list[ShaftFeature] = field(default_factory=list)
    skeleton: list[SkeletonSegment] = field(default_factory=list)
    tool_tip: PointFeature | None = None
    joint_limits: np.ndarray | None = None  # (n_joints, 2)

    @property
    def n_dh(self) -> int:
        return len(self.dh)

    @property
    def n_joints(self) -> int:
        """Length of the joint vector: the DH joints, plus the jaw with a gripper."""
        return self.n_dh + (1 if self.has_gripper else 0)

    @property
    def n_links(self) -> int:
        return self.n_dh + (2 if self.has_gripper else 0)

    def to_json(self) -> dict:
        """The robot.json document (format doc schema)."""
        doc = {
            "DH_params": [{"type": j.type, "alpha": j.alpha, "A": j.A, "theta": j.theta,
                           "D": j.D, "offset": j.offset} for j in self.dh],
            "has_gripper": self.has_gripper,
            "point_features": [{"name": p.name, "link": p.link, "position": list(p.position),
                                **({"radius": p.radius} if p.radius > 0 else {})}
                               for p in self.point_features],
            "shaft_features": [{"name": s.name, "link": s.link, "position": list(s.position),
                                "direction": list(s.direction), "radius": s.radius,
                                **({"end": s.end} if s.end is not None else {})}
                               for s in self.shaft_features],
            "skeleton_structure": [{"link1": s.link1, "position1": list(s.position1),
                                    "link2": s.link2, "position2": list(s.position2)}
                                   for s in self.skeleton],
        }
        if self.tool_tip is not None:
            doc["tool_tip"] = {"link": self.tool_tip.link, "position": list(self.tool_tip.position)}
        if self.joint_limits is not None:
            doc["joint_limits"] = [[float(a), float(b)] for a, b in self.joint_limits]
        return doc


# -- parsing helpers ------------------------------------------------------------------
class _Doc:
    """Typed access to a JSON object that names the file and field on error."""

    def __init__(self, path: Path, where: str = ""):
        self.path = path
        self.where = where

    def fail(self, field_: str, why: str):
        raise InputError(f"{self.path}: {self.where}{field_}: {why}")

    def get(self, obj: dict, key: str, kind=float, default=None, required=True, bound=None):
        """obj[key] as ``kind`` (float, int, bool, str or "vec3"); numbers must be real
        JSON numbers (not bools or strings), finite, and ``|x| <= bound`` when given."""
        if not isinstance(obj, dict):
            self.fail(key, "expected an object")
        if key not in obj:
            if required and default is None:
                self.fail(key, "missing key")
            return default
        v = obj[key]
        if kind is float or kind is int:
            if not is_number(v) or (kind is int and not (isinstance(v, int) or float(v).is_integer())):
                self.fail(key, f"expected {kind.__name__}, got {v!r}")
            self._bound(key, v, bound)
            return kind(v)
        if kind == "vec3":
            if not isinstance(v, list) or len(v) != 3 or not all(is_number(x) for x in v):
                self.fail(key, f"expected a list of 3 numbers, got {v!r}")
            for x in v:
                self._bound(key, x, bound)
            return tuple(float(x) for x in v)
        if not isinstance(v, kind):
            self.fail(key, f"expected {getattr(kind, '__name__', kind)}, got {v!r}")
        return v

    def _bound(self, key: str, x, bound):
        if bound is not None and not abs(x) <= bound:
            self.fail(key, f"{x!r} is out of range (|value| <= {bound:g})")

    def items(self, doc: dict, key: str, limit: int | None = None) -> list:
        """doc[key] as a list of objects ([] when absent or null), of at most ``limit``."""
        v = doc.get(key)
        if v is None:
            return []
        if not isinstance(v, list):
            self.fail(key, f"expected a list of objects, got {type(v).__name__}")
        if limit is not None and len(v) > limit:
            self.fail(key, f"{len(v)} entries; at most {limit} are tracked")
        for i, o in enumerate(v):
            if not isinstance(o, dict):
                self.fail(f"{key}[{i}]", f"expected an object, got {o!r}")
        return v


#: plausibility bounds of robot.json's numbers: lengths (m), angles (rad), link indices
MAX_LENGTH_M = 10.0
#: point features (painted markers) a tool may carry: every one is projected for every
#: particle and paired with every detection, so memory and time grow with the count
MAX_POINT_FEATURES = 64
MAX_ANGLE_RAD = 4 * math.pi
MAX_LINK = 1000


def _dh_joint(d: _Doc, obj: dict, i: int, lower_keys: bool = False) -> DHJoint:
    d.where = f"joint {i + 1}: "
    typ = d.get(obj, "type", str)
    if typ not in ("revolute", "prismatic"):
        d.fail("type", f"expected 'revolute' or 'prismatic', got {typ!r}")
    conv = obj.get("convention", "modified")
    if conv != "modified":
        d.fail("convention", f"only modified DH is supported, got {conv!r}")
    keyA = "A" if "A" in obj or not lower_keys else "a"
    keyD = "D" if "D" in obj or not lower_keys else "d"
    L, ang = MAX_LENGTH_M, MAX_ANGLE_RAD
    j = DHJoint(typ, d.get(obj, "alpha", bound=ang), d.get(obj, keyA, bound=L), d.get(obj, "theta", bound=ang),
                d.get(obj, keyD, bound=L), d.get(obj, "offset", default=0.0, required=False, bound=max(L, ang)))
    d.where = ""
    return j


def _links(n: int, has_gripper: bool) -> int:
    return n + (2 if has_gripper else 0)


def _check_link(d: _Doc, link: int, n_links: int, what: str):
    if not 0 <= link <= n_links:
        d.fail(what, f"link {link} does not exist (links are 0..{n_links})")


def parse_robot(doc: dict, path: Path) -> RobotDescription:
    """Build a RobotDescription from a parsed robot.json document."""
    d = _Doc(path)
    if not isinstance(doc, dict):
        d.fail("document", "expected a JSON object")
    raw = d.get(doc, "DH_params", list)
    if not isinstance(raw, list) or not raw:
        d.fail("DH_params", "expected a non-empty list of joints")
    dh = [_dh_joint(d, o, i) for i, o in enumerate(raw)]
    grip = d.get(doc, "has_gripper", bool, default=False, required=False)
    n_links = _links(len(dh), grip)

    L = MAX_LENGTH_M
    points = []
    for i, o in enumerate(d.items(doc, "point_features", MAX_POINT_FEATURES)):
        d.where = f"point_features[{i}]: "
        p = PointFeature(d.get(o, "name", str, default=f"point_{i}", required=False),
                         d.get(o, "link", int, bound=MAX_LINK), d.get(o, "position", "vec3", bound=L),
                         d.get(o, "radius", default=0.0, required=False, bound=L))
        _check_link(d, p.link, n_links, "link")
        if not 0 <= p.radius <= 0.01:
            d.fail("radius", "must be in [0, 0.01] (metres: a painted marker's disc; 0: a point)")
        if not p.name.strip() or any(q.name == p.name for q in points):
            d.fail("name", f"{p.name!r} is empty or names an earlier point feature too (--tip-feature "
                           "and the outputs name features by it)")
        points.append(p)
    shafts = []
    for i, o in enumerate(d.items(doc, "shaft_features")):
        d.where = f"shaft_features[{i}]: "
        s = ShaftFeature(d.get(o, "name", str, default=f"shaft_{i}", required=False),
                         d.get(o, "link", int, bound=MAX_LINK), d.get(o, "position", "vec3", bound=L),
                         d.get(o, "direction", "vec3", bound=L), d.get(o, "radius", bound=L),
                         d.get(o, "end", default=None, required=False, bound=L))
        _check_link(d, s.link, n_links, "link")
        if not np.linalg.norm(s.direction) > 1e-9:
            d.fail("direction", f"must be non-zero, got {np.asarray(s.direction).tolist()}")
        if not 0 < s.radius <= 0.1:
            d.fail("radius", f"must be in (0, 0.1] m, got {s.radius:g}"
                   + (" (millimetres? robot.json is in metres)" if 0.1 < s.radius <= 100 else ""))
        shafts.append(s)
    skel = []
    for i, o in enumerate(d.items(doc, "skeleton_structure")):
        d.where = f"skeleton_structure[{i}]: "
        s = SkeletonSegment(d.get(o, "link1", int, bound=MAX_LINK), d.get(o, "position1", "vec3", bound=L),
                            d.get(o, "link2", int, bound=MAX_LINK), d.get(o, "position2", "vec3", bound=L))
        _check_link(d, s.link1, n_links, "link1")
        _check_link(d, s.link2, n_links, "link2")
        skel.append(s)
    tip = None
    if doc.get("tool_tip") is not None:
        d.where = "tool_tip: "
        o = doc["tool_tip"]
        tip = PointFeature("tool_tip", d.get(o, "link", int, bound=MAX_LINK), d.get(o, "position", "vec3", bound=L))
        _check_link(d, tip.link, n_links, "link")
    d.where = ""
    limits = _joint_limits(d, doc.get("joint_limits"), len(dh), len(dh) + (1 if grip else 0))
    return RobotDescription(dh, grip, points, shafts, skel, tip, limits)


def _joint_limits(d: _Doc, raw, n_dh: int, n_j: int) -> np.ndarray | None:
    """robot.json ``joint_limits``: n_dh or n_j pairs [qmin, qmax] of finite numbers, qmin <= qmax."""
    if raw is None:
        return None
    counts = f"{n_dh}" if n_j == n_dh else f"{n_dh} (the DH joints) or {n_j} (and the jaw)"
    if not isinstance(raw, list) or len(raw) not in (n_dh, n_j):
        got = f"{len(raw)} pairs" if isinstance(raw, list) else json.dumps(raw)[:80]
        jaw = isinstance(raw, list) and n_j == n_dh and len(raw) == n_dh + 1
        d.fail("joint_limits", f"expected {counts} pairs [qmin, qmax], got {got}"
               + (" (a jaw pair, but has_gripper is false)" if jaw else ""))
    bad = next((i for i, p in enumerate(raw)
                if not (isinstance(p, list) and len(p) == 2 and all(is_number(x) for x in p))), None)
    if bad is not None:
        d.fail("joint_limits", f"pair {bad} is not [qmin, qmax] of two numbers: {json.dumps(raw[bad])[:80]}")
    limits = np.asarray(raw, dtype=float)
    if np.any(limits[:, 0] > limits[:, 1]):
        d.fail("joint_limits", "a pair has qmin > qmax")
    return limits




def load_robot_json(path: str | Path) -> RobotDescription:
    """Read robot.json; raise InputError naming file and field on any problem."""
    path = Path(path)
    return parse_robot(read_json(path), path)


def save_robot_json(path: str | Path, robot: RobotDescription) -> None:
    Path(path).write_text(json.dumps(robot.to_json(), indent=2))


def _json_kind(v) -> str:
    """The JSON name of a parsed value's type ("an array", "a string", "null", ...)."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    return {list: "an array", str: "a string", int: "a number", float: "a number"}.get(type(v), "an object")


def _dvrk_dh(path: Path) -> tuple[list[DHJoint], dict]:
    doc = read_json(path)
    d = _Doc(path)
    if not isinstance(doc, dict):
        d.fail("document", f"expected a JSON object (a dVRK configuration file), got {_json_kind(doc)}")
    dh = doc.get("DH")
    if not isinstance(dh, dict):
        d.fail("DH", "missing" if dh is None else f"expected an object, got {_json_kind(dh)}")
    conv = dh.get("convention", "modified")
    if conv != "modified":
        d.fail("DH.convention", f"only modified DH is supported, got {conv!r}")
    items = dh.get("links", dh.get("joints"))
    if not isinstance(items, list) or not items:
        d.fail("DH.links", "expected a non-empty list")
    return [_dh_joint(d, o, i, lower_keys=True) for i, o in enumerate(items)], doc


def load_dvrk_config(arm_file: str | Path, tool_file: str | Path,
                     features_from: RobotDescription | str | Path | None = None,
                     has_gripper: bool | None = None) -> RobotDescription:
    """Combine a dVRK arm file (joints 1-3) and tool file (joints 4-6) into one chain.

    If the arm file lists the whole PSM (six or more joints, the older
    ``psm-large-needle-driver.json`` layout), its first three are taken and the
    tool file supplies the rest: its 3 joints, or the last 3 of a whole-PSM file's 6
    (any other count is refused). The dVRK files hold no visual features:
    ``features_from`` (a RobotDescription, or a robot.json's path) supplies them. The jaw exists when
    the tool file has a ``jaw`` section unless ``has_gripper`` overrides.
    """
    arm, _ = _dvrk_dh(Path(arm_file))
    tool, tool_doc = _dvrk_dh(Path(tool_file))
    if len(arm) != 3 and len(arm) < 6:
        raise InputError(f"{arm_file}: DH: expected the arm's 3 joints or a whole PSM's 6 or more, got {len(arm)}")
    if len(tool) not in (3, 6):
        raise InputError(f"{tool_file}: DH: expected the tool's 3 joints (4-6) or a whole PSM's 6, got {len(tool)}")
    tool = tool[-3:]
    grip = has_gripper if has_gripper is not None else "jaw" in tool_doc
    base = load_robot_json(features_from) if isinstance(features_from, (str, Path)) else features_from
    if base is None:
        return RobotDescription(arm[:3] + tool, grip)
    return RobotDescription(arm[:3] + tool, grip, base.point_features, base.shaft_features,
                            base.skeleton, base.tool_tip, base.joint_limits)
