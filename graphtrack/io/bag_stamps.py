"""Stamps of bag messages and the joint readings sorted by them (pass 1 of
:mod:`graphtrack.io.bag`): header stamps in integer nanoseconds, the nearest reading
to an image's stamp and how far it is."""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from graphtrack.io.stamps import median_interval


# -- stamps -----------------------------------------------------------
def to_ns(stamp: float) -> int:
    """Seconds (float) -> integer nanoseconds, exact to the float's resolution."""
    sec = math.floor(stamp)
    ns = int(round((stamp - sec) * 1e9))
    return int(sec) * 1_000_000_000 + ns


def header_ns(msg, fallback_ns: int) -> int:
    st = msg.header.stamp
    ns = int(st.sec) * 1_000_000_000 + int(st.nanosec)
    return ns if ns != 0 else int(fallback_ns)


def raw_header_ns(raw: bytes, ros2: bool) -> int:
    """Header stamp straight from serialized bytes (no image decoding): ROS 1 seq,sec,nsec;
    CDR: 4-byte encapsulation, then sec,nanosec."""
    if ros2:
        endian = "<" if raw[1] == 1 else ">"
        sec, nsec = struct.unpack_from(endian + "iI", raw, 4)
    else:
        sec, nsec = struct.unpack_from("<II", raw, 4)
    return sec * 1_000_000_000 + nsec


# -- joint table ------------------------------------------------------------------------
@dataclass
class JointTable:
    """Joint or jaw readings sorted by header stamp: stamps (N,) ns, values (N, m) padded
    with NaN, lengths (N,) the number of values each message carried."""

    stamps: np.ndarray
    values: np.ndarray
    lengths: np.ndarray

    @classmethod
    def build(cls, stamps: list[int], values: list[np.ndarray]) -> "JointTable":
        n = len(stamps)
        width = max((len(v) for v in values), default=0)
        arr = np.full((n, width), np.nan)
        lengths = np.zeros(n, dtype=int)
        for i, v in enumerate(values):
            arr[i, : len(v)] = v
            lengths[i] = len(v)
        order = np.argsort(np.asarray(stamps, dtype=np.int64), kind="stable")
        return cls(np.asarray(stamps, dtype=np.int64)[order], arr[order], lengths[order])

    def _nearest_index(self, t_ns: int) -> int:
        i = int(np.searchsorted(self.stamps, t_ns))
        if i == len(self.stamps) or (i > 0 and t_ns - self.stamps[i - 1] <= self.stamps[i] - t_ns):
            i -= 1
        return i

    def nearest(self, t_ns: int) -> np.ndarray:
        """The reading whose stamp is nearest t_ns (ties: the earlier); empty if none."""
        if len(self.stamps) == 0:
            return np.zeros(0)
        i = self._nearest_index(t_ns)
        return self.values[i, : self.lengths[i]]

    def tolerance_s(self, floor: float) -> float:
        """s: how far a frame may be from its nearest reading: ``floor``, or 3 median
        periods of the readings when that is more (a topic recorded at a low rate)."""
        return max(floor, 3.0 * self._period_s)

    @cached_property
    def _period_s(self) -> float:
        """The median interval between readings (s; 0 with fewer than two)."""
        return median_interval(self.stamps) / 1e9

    def gap_s(self, t_ns: int) -> float:
        """|t_ns - the nearest reading's stamp| in seconds (inf if none)."""
        if len(self.stamps) == 0:
            return math.inf
        return abs(int(t_ns) - int(self.stamps[self._nearest_index(t_ns)])) / 1e9
