"""A stereo bag's right images paired with its left ones, in one forward pass
(:class:`graphtrack.io.bag.BagSource` pass 2).

The right images are read alongside the left ones, in bag order, with a small
look-ahead; a left image takes the right image whose header stamp is nearest its
own if they differ by at most half the shorter median period of the two streams
(two free-running cameras at 30 frames/s are up to 16.7 ms apart; a slower stream
must not pair one image with a farther frame), or ``RIGHT_SYNC_S`` if that is more
(and on the first frame, before the left period is known). Left and right stamps
must increase in bag order. A left image without one (missing, or not decodable)
gets None, counted in the source's ``right_skips``.
"""
from __future__ import annotations

from graphtrack.errors import one_line
from graphtrack.io.bag_stamps import raw_header_ns
from graphtrack.io.image_msg import decode_image
from graphtrack.io.stamps import median_interval

#: s, the least largest left-right stamp difference of a stereo pair (module doc)
RIGHT_SYNC_S = 0.010


class RightMatcher:
    """Right images matched to left stamps in one forward pass (module doc)."""

    def __init__(self, source, messages):
        self.src, self.it, self.buf, self.done = source, messages, [], False
        self.recent: list[int] = []    # the last right stamps pulled (ns), for their period
        self.lefts: list[int] = []     # the last left stamps asked for (ns)
        self.tol = int(RIGHT_SYNC_S * 1e9)

    def _tolerance(self) -> int:
        """ns: half the shorter median period of the right stamps pulled and the left ones
        asked for so far (a slower stream must not pair one image with a farther frame),
        RIGHT_SYNC_S at least; RIGHT_SYNC_S until both periods are known (the first frame)."""
        periods = [median_interval(stamps) for stamps in (self.recent, self.lefts)]
        if min(periods) <= 0:
            return int(RIGHT_SYNC_S * 1e9)
        return max(int(RIGHT_SYNC_S * 1e9), int(min(periods)) // 2)

    def _pull(self) -> None:
        try:
            t, raw, deser = next(self.it)
        except StopIteration:
            self.done = True
            return
        except Exception as e:  # noqa: BLE001 - damaged right data: the rest is left-only
            self.done = True
            self.src.warnings.append(f"{self.src.path}: {self.src.right_topic} unreadable ({one_line(e)}); "
                                     "later frames are left-only")
            return
        ns = raw_header_ns(raw, self.src.ros2) if len(raw) >= 12 else 0
        try:  # deserialized now: the reader behind ``deser`` closes when the messages end
            msg = deser(raw, self.src.right_type)
        except Exception:  # noqa: BLE001 - decoded below as corrupt
            msg = None
        self.buf.append((ns or t, msg))
        self.recent = self.recent[-15:] + [ns or t]
        self.tol = self._tolerance()

    def image(self, t_ns: int):
        """The decoded right image for left stamp t_ns, or None (counted in right_skips)."""
        self.lefts = self.lefts[-15:] + [t_ns]
        self.tol = self._tolerance()
        while not self.done and (not self.buf or self.buf[-1][0] <= t_ns + self.tol or len(self.recent) < 2):
            self._pull()   # up to the first beyond the tolerance, and two for a period
        while self.buf and self.buf[0][0] < t_ns - self.tol:
            self.buf.pop(0)
        best = min(range(len(self.buf)), key=lambda k: abs(self.buf[k][0] - t_ns), default=None)
        if best is None or abs(self.buf[best][0] - t_ns) > self.tol:
            self.src.right_skips["missing"] += 1
            return None
        _, msg = self.buf[best]
        del self.buf[:best + 1]
        try:
            return decode_image(msg, self.src.right_type, str(self.src.path))
        except Exception:  # noqa: BLE001 - a corrupt right image: left-only for this frame
            self.src.right_skips["corrupt"] += 1
            return None
