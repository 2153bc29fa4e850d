"""Reading ROS bags: the bag form of a sequence (format doc, "The bag"); writing
is :mod:`graphtrack.io.bag_write`.

Reading (ROS 1 ``.bag`` files and ROS 2 bag folders, via ``rosbags``) is
streamed in two passes so that a 10 GB bag never sits in memory (images decoded
by :mod:`graphtrack.io.image_msg`):

1. the small joint and jaw messages (``/dvrk/PSM1/state_joint_current`` and
   ``/dvrk/PSM1/state_jaw_current``, or dVRK 2.x's ``/PSM1/measured_js`` and
   ``/PSM1/jaw/measured_js``; :mod:`graphtrack.io.topics`) -> arrays of header
   stamps (ns) and positions;
2. the left images (``/stereo/left/image``, else ``/stereo/left/image/compressed``)
   in bag order, decoded one at a time; each takes the joint and jaw messages
   whose header stamps are nearest its own header stamp (ties: the earlier one);
   with no joint (or jaw) reading within ``MAX_JOINT_GAP_S``, or 3 median periods of
   that topic's readings if more, the frame is skipped (``no_joint_reading``: joints
   not recorded then, or stamped on another clock).
   Stereo bags: the right images (``/stereo/right/image[/compressed]``) are read
   alongside and paired by stamp (:mod:`graphtrack.io.bag_right`); a left image
   without one gets ``image_right`` None and is counted in ``BagSource.right_skips``.

A message whose header stamp is zero (never set by its publisher) uses its bag
record time instead.

Truncated ROS 1 bags: a bag whose index is missing or damaged (recording
killed, disk full, partial copy, ``.bag.active``) is read by a linear scan of its
records (:mod:`graphtrack.io.bag1scan`): every complete message before the
damage is used, ``BagSource.truncated`` is True and ``BagSource.warnings`` says
so. Damage inside an indexed ROS 1 bag (a chunk that does not decompress, a
malformed record) met by the joint pass, before any frame, is read the same way,
up to the damage; met later, in image data only, it raises InputError naming the
bag after the frames before it were yielded ("unreadable after frame k"); frame
numbers are never shifted silently. A damaged ROS 2 bag raises InputError.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from graphtrack.errors import FrameError, InputError, one_line
from graphtrack.io.bag1scan import Bag1Scan
from graphtrack.io.bag_right import RightMatcher
from graphtrack.io.bag_stamps import JointTable, header_ns, raw_header_ns
from graphtrack.io.frame import Frame
from graphtrack.io.joint_names import in_dh_order
from graphtrack.io.image_msg import COMPRESSED_TYPE, IMAGE_TYPE, decode_image, noise_span
from graphtrack.io.topics import IMAGE_TOPICS, RIGHT_IMAGE_TOPICS, TopicSelection, resolve_right, resolve_topics

IMAGE_TOPIC, COMPRESSED_TOPIC = IMAGE_TOPICS
RIGHT_IMAGE_TOPIC, RIGHT_COMPRESSED_TOPIC = RIGHT_IMAGE_TOPICS
JOINT_TYPE = "sensor_msgs/msg/JointState"
#: s, the farthest a frame's nearest joint (jaw) reading may be from its image's stamp,
#: or 3 median reading periods when that is more (dVRK joint states come at 100 Hz or
#: more); farther, the frame is skipped as no_joint_reading
MAX_JOINT_GAP_S = 0.2


def open_bag(path: Path) -> AnyReader:
    """A rosbags reader of a ROS 1 .bag file or a ROS 2 bag folder, with the typestore of its
    ROS version for messages whose definitions the bag does not carry."""
    store = get_typestore(Stores.ROS2_HUMBLE if Path(path).is_dir() else Stores.ROS1_NOETIC)
    return AnyReader([Path(path)], default_typestore=store)


# -- the reader -------------------------------------------------------------------------
class BagSource:
    """One ROS 1 bag file or ROS 2 bag folder: validated at construction, streamed later.

    Attributes: path, arm, image_topic, joint_topic, jaw_topic (chosen by
    :func:`graphtrack.io.topics.resolve_topics` from ``selection``), n_images
    (frame count, from the index; from a scan for truncated bags), has_jaw,
    truncated, warnings (lines for the user). Raises InputError naming the bag
    (and topic) when it cannot be read or lacks the left image topic or the
    joint topic.
    """

    def __init__(self, path: str | Path, selection: TopicSelection = TopicSelection()):
        self.path = Path(path)
        self.selection = selection
        self.ros2 = self.path.is_dir()
        self.truncated = False
        self.warnings: list[str] = []
        self._table: tuple[JointTable, JointTable] | None = None
        self._stamps: np.ndarray | None = None
        self._scan_images: list[int] | None = None
        self.right_topic: str | None = None
        self.right_skips = {"missing": 0, "corrupt": 0}
        try:
            topics = self._indexed_topics()
            self.scan = False
        except InputError:
            raise
        except Exception as e:  # noqa: BLE001 - rosbags raises many types on damaged files
            if self.ros2 or not self._has_ros1_magic():
                raise InputError(f"{self.path}: cannot read bag ({one_line(e)})") from None
            self.scan = True
            topics = self._scan_topics(e)
        self._choose_topics(topics)

    # -- opening ------------------------------------------------------------------------
    def _reader(self):
        return open_bag(self.path)

    def _indexed_topics(self) -> dict[str, tuple[str, int]]:
        if not self.ros2 and self.path.suffix != ".bag":
            raise ValueError("not named .bag (an unindexed .bag.active?)")
        with self._reader() as r:
            return {name: (info.msgtype, info.msgcount) for name, info in r.topics.items()}

    def _has_ros1_magic(self) -> bool:
        try:
            with self.path.open("rb") as f:
                return f.readline() == b"#ROSBAG V2.0\n"
        except OSError:
            return False

    def _scan_topics(self, err: Exception) -> dict[str, tuple[str, int]]:
        """Unindexed/truncated ROS 1 bag: one scan pass collects joints and image stamps."""
        store = get_typestore(Stores.ROS1_NOETIC)
        scan = Bag1Scan(self.path)
        counts: dict[str, list] = {}
        joints: dict[str, tuple[list, list]] = {}
        img_stamps: dict[str, list[int]] = {}
        for conn, t, raw in scan.messages():
            counts.setdefault(conn.topic, [conn.msgtype, 0])[1] += 1
            if conn.msgtype == JOINT_TYPE:
                self._add_joint(joints.setdefault(conn.topic, ([], [], [])), store.deserialize_ros1, raw,
                                conn.msgtype, t)
            elif conn.msgtype in (IMAGE_TYPE, COMPRESSED_TYPE):
                ns = raw_header_ns(raw, False) if len(raw) >= 12 else 0
                img_stamps.setdefault(conn.topic, []).append(ns or t)
        self.truncated = True
        why = f"{one_line(err)}; {scan.stop_reason or 'no damage found in the records'}"
        self.warnings.append(f"{self.path}: bag index unusable ({why}); read by scanning its "
                             "records, frames after the damage are missing")
        self._scan_warning = len(self.warnings) - 1     # _choose_topics adds the last good frame
        self._scan_joints = joints
        self._scan_stamps = img_stamps
        return {k: (v[0], v[1]) for k, v in counts.items()}

    def _choose_topics(self, topics: dict[str, tuple[str, int]]) -> None:
        if self.scan and not any(t[0] in (IMAGE_TYPE, COMPRESSED_TYPE) for t in topics.values()):
            raise InputError(f"{self.warnings[-1]}; no complete left image found")
        chosen = resolve_topics(topics, self.selection, str(self.path))
        self.arm, self.image_topic = chosen.arm, chosen.image
        self.joint_topic, self.jaw_topic = chosen.joint, chosen.jaw
        if chosen.note:
            self.warnings.append(chosen.note)
        self.image_type, self.n_images = topics[self.image_topic]
        if self.image_type not in (IMAGE_TYPE, COMPRESSED_TYPE):
            raise InputError(f"{self.path}: topic {self.image_topic} has type {self.image_type}, expected "
                             f"{IMAGE_TYPE} or {COMPRESSED_TYPE}")
        for t in (self.joint_topic, self.jaw_topic):
            if t in topics and topics[t][0] != JOINT_TYPE:
                raise InputError(f"{self.path}: topic {t} has type {topics[t][0]}, expected {JOINT_TYPE}")
        self.has_jaw = topics.get(self.jaw_topic, (None, 0))[1] > 0
        topic, note = resolve_right(topics, self.selection, str(self.path), self.image_topic)
        if topic is not None:
            if topics[topic][0] not in (IMAGE_TYPE, COMPRESSED_TYPE):
                self.warnings.append(f"{self.path}: topic {topic} has type {topics[topic][0]}, expected "
                                     f"{IMAGE_TYPE} or {COMPRESSED_TYPE}; right images ignored")
            else:
                self.right_topic, self.right_type = topic, topics[topic][0]
                self.warnings += [note] if note else []
        if self.scan:
            empty = ([], [], [])
            self._table = self._tables(self._scan_joints.get(self.joint_topic, empty),
                                       self._scan_joints.get(self.jaw_topic, empty))
            # images stamped after the last surviving joint (jaw) reading lost the readings
            # that sync them: the recording ends before them
            stamps = np.asarray(self._scan_stamps.get(self.image_topic, []), dtype=np.int64)
            joints, jaw = self._table
            last = min([t.stamps[-1] for t in ((joints, jaw) if self.has_jaw else (joints,)) if len(t.stamps)]
                       or [np.iinfo(np.int64).max])
            beyond = np.flatnonzero(stamps > last)
            self.n_images = int(beyond[0]) if beyond.size else len(stamps)
            self._stamps = stamps[: self.n_images]
            if self.n_images:
                self.warnings[self._scan_warning] += f" (the last good frame is {self.n_images - 1})"

    def __len__(self) -> int:
        return int(self.n_images)

    # -- pass 1: joints -----------------------------------------------------------------
    def _add_joint(self, acc: tuple[list, list, list], deser, raw, msgtype, t_ns) -> None:
        try:
            msg = deser(raw, msgtype)
        except Exception:  # noqa: BLE001 - one undecodable reading: the nearest other one is used
            self.warnings.append(f"{self.path}: skipped an undecodable joint message at t={t_ns} ns")
            return
        acc[0].append(header_ns(msg, t_ns))
        acc[1].append(np.asarray(msg.position, dtype=float).ravel())
        acc[2].append(tuple(getattr(msg, "name", None) or ()))

    def joint_tables(self) -> tuple[JointTable, JointTable]:
        """(joints, jaw) tables, read on first use (pass 1)."""
        if self._table is None:
            acc = {self.joint_topic: ([], [], []), self.jaw_topic: ([], [], [])}
            try:
                with self._reader() as r:
                    conns = [c for c in r.connections if c.topic in acc]
                    for c, t, raw in r.messages(connections=conns):
                        self._add_joint(acc[c.topic], r.deserialize, raw, c.msgtype, t)
            except InputError:
                raise
            except Exception as e:  # noqa: BLE001
                if self.ros2 or not self._has_ros1_magic():
                    raise InputError(f"{self.path}: damaged bag data while reading {self.joint_topic} "
                                     f"({one_line(e)})") from None
                # a damaged chunk of an indexed ROS 1 bag: read up to it as a truncated bag is
                self.scan = True
                self._choose_topics(self._scan_topics(e))
                return self.joint_tables()
            self._table = self._tables(acc[self.joint_topic], acc[self.jaw_topic])
        self._check_jaw(self._table[1])
        return self._table

    def _tables(self, joints: tuple[list, list, list], jaw: tuple[list, list, list]) -> tuple[JointTable, JointTable]:
        """(joints, jaw) tables of the accumulated (stamps, values, names); the joints' values in
        DH order by their names (:mod:`graphtrack.io.joint_names`)."""
        stamps, values, names = joints
        values = in_dh_order(values, names, f"{self.path}: {self.joint_topic}")
        return JointTable.build(stamps, values), JointTable.build(*jaw[:2])

    def _stale(self, joints: JointTable, jaw: JointTable, stamp_ns: int) -> str | None:
        """Why the frame stamped ``stamp_ns`` has no usable joint (or, with a jaw topic,
        jaw) reading: the nearest is farther than the table's tolerance (module doc); None
        when both are near enough."""
        for topic, table in ((self.joint_topic, joints), (self.jaw_topic, jaw)):
            if table is jaw and not self.has_jaw:
                continue
            given = self.selection.joint_gap
            gap, tol = table.gap_s(stamp_ns), given if given is not None else table.tolerance_s(MAX_JOINT_GAP_S)
            if gap > tol:
                return (f"the nearest {topic} reading is {gap:.3f} s from the image's stamp (more than "
                        f"{tol:.3g} s: not recorded then, or stamped on another clock; --max-joint-gap)")
        return None

    def _check_jaw(self, jaw: JointTable) -> None:
        """InputError when a jaw message holds more than one position (e.g. --jaw-topic
        naming the joint topic); an empty one leaves its frames' jaw NaN (nan_joints)."""
        bad = np.flatnonzero(jaw.lengths > 1)
        if self.has_jaw and bad.size:
            raise InputError(f"{self.path}: {self.jaw_topic}: a jaw message holds one position, but the one "
                             f"stamped {jaw.stamps[bad[0]] / 1e9:.3f} s holds {jaw.lengths[bad[0]]} "
                             "(is --jaw-topic the joint topic?)")

    # -- pass 2: images -----------------------------------------------------------------
    def _image_messages(self, topic: str | None = None) -> Iterator[tuple[int, bytes, object]]:
        """(bag time ns, raw bytes, deserializer) per image of ``topic`` (default: the left
        images), in bag order."""
        topic = topic or self.image_topic
        if self.scan:
            store = get_typestore(Stores.ROS1_NOETIC)
            for c, t, raw in Bag1Scan(self.path).messages():
                if c.topic == topic:
                    yield t, raw, store.deserialize_ros1
            return
        with self._reader() as r:
            conns = [c for c in r.connections if c.topic == topic]
            yield from ((t, raw, r.deserialize) for _, t, raw in r.messages(connections=conns))

    def frames(self, start: int = 0, right: bool = True):
        """Yield, per left image from ``start`` on, a Frame (unchecked) or a FrameError.

        Frame.joints: the nearest joint message's ``position``; Frame.jaw: the
        nearest jaw message's first value, NaN when the bag has no jaw topic.
        right: False leaves the right images unread (Frame.image_right None, nothing counted).
        """
        joints, jaw = self.joint_tables()
        index = -1
        decoded = False   # an image of this pass has decoded
        it = self._image_messages()
        right = (RightMatcher(self, self._image_messages(self.right_topic))
                 if self.right_topic and right else None)
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as e:  # noqa: BLE001
                raise InputError(f"{self.path}: unreadable after frame {index} "
                                 f"({one_line(e)})") from None
            index += 1
            if index >= self.n_images:  # truncated bag: images past the last joint reading
                return
            if index < start:
                continue
            t_bag, raw, deser = item
            try:
                msg = deser(raw, self.image_type)
                stamp_ns = header_ns(msg, t_bag)
                if (stale := self._stale(joints, jaw, stamp_ns)) is not None:   # before decoding: cheap
                    yield FrameError(index, "no_joint_reading", stale)
                    continue
                image = decode_image(msg, self.image_type, f"{self.path}: {self.image_topic}")
            except InputError as e:
                if not decoded:   # the first image's encoding is unreadable: every frame would fail alike
                    raise
                yield FrameError(index, "corrupt_image", one_line(e).removeprefix(f"{self.path}: "))
                continue
            except Exception as e:  # noqa: BLE001 - undecodable message or image
                yield FrameError(index, "corrupt_image", f"{self.image_topic}: {one_line(e)}")
                continue
            decoded = True
            if self.image_type == IMAGE_TYPE and (why := noise_span(image)) is not None:
                yield FrameError(index, "corrupt_image", f"{self.image_topic}: {why}")
                continue
            if self.has_jaw:
                j = jaw.nearest(stamp_ns)
                jaw_value = float(j[0]) if j.size else float("nan")
            else:
                jaw_value = float("nan")
            yield Frame(index, stamp_ns / 1e9, image, joints.nearest(stamp_ns).copy(), jaw_value,
                        image_right=None if right is None else right.image(stamp_ns))

    def stamps(self) -> np.ndarray:
        """Header stamps (s) of the left images, in frame order (one extra pass, no decoding)."""
        if self._stamps is None:
            with self._reader() as r:
                conns = [c for c in r.connections if c.topic == self.image_topic]
                self._stamps = np.array([raw_header_ns(raw, self.ros2) or t
                                         for _, t, raw in r.messages(connections=conns)], dtype=np.int64)
        return self._stamps / 1e9
