"""Open a sequence folder (format doc) and stream its frames.

    rec = open_recording("seq/")            # validates everything cheap, reads no image
    len(rec)                                # frames, from the bag index / joints.csv
    for item in rec.frames():               # Frame or FrameError, in frame order
        if isinstance(item, FrameError):
            skipped[item.reason] += 1
            continue
        ...

Whole-recording problems raise :class:`~graphtrack.errors.InputError` with one
line naming the file, topic or field: a missing robot.json,
camera_calibration.yaml or handeye.yaml; no recording or more than one bag; a
bag without the left image topic or the joint topic; an unreadable bag; a
wrong joints.csv header.

Per-frame problems are YIELDED (not raised) as
:class:`~graphtrack.errors.FrameError` with these ``reason`` keys:

- ``corrupt_image``: the image message / file / video frame does not decode;
- ``missing_image``: a row of joints.csv whose image file is not in frames/;
- ``video_ended``: a row of joints.csv past the last frame video.mp4 decodes;
- ``image_size``: the image size differs from ``ImageSize`` in camera_calibration.yaml;
- ``joint_count``: the joint reading does not hold the expected number of DH joints;
- ``nan_joints``: a joint (or, when the recording has jaw readings, the jaw) is NaN/inf;
- ``joint_range``: a joint (or jaw) reading no arm makes in radians and metres: a
  revolute one beyond a full turn, a prismatic one beyond 1 m
  (:mod:`graphtrack.io.joint_units`; a joints.csv whose rows mostly are is refused);
- ``flat_image``: the image's bottom quarter is one flat colour and the rest is not (a
  damaged JPEG that decodes with a flat tail).

Stereo recordings (right images plus K2, D2, R, T): each Frame's ``image_right``
holds the right image matched by stamp (folder form: the same file name in
frames_right/); a missing, corrupt or wrongly sized right image gives None and
is counted in ``rec.right_skips`` (and a line in ``rec.warnings``): that frame is
left-only. ``rec.labels_right`` holds labels_right.csv.

Truncated ROS 1 bags (index missing or damaged) are read up to the damage:
all complete frames are yielded, ``rec.truncated`` is True and ``rec.warnings``
holds a line for the user. See :mod:`graphtrack.io.bag`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from graphtrack.errors import FrameError, InputError, read_json
from graphtrack.geometry.camera import Calibration, load_calibration
from graphtrack.io.bag import BagSource
from graphtrack.io.consistency import consistency_notes
from graphtrack.io.folder import FolderSource
from graphtrack.io.frame_checks import frame_problem, right_problem
from graphtrack.io.handeye import load_handeye
from graphtrack.io.joint_units import check_table, joint_bounds
from graphtrack.io.labels import read_labels
from graphtrack.io.topics import TopicSelection
from graphtrack.robot.description import load_robot_json

REQUIRED = ("robot.json", "camera_calibration.yaml", "handeye.yaml")


@dataclass
class Recording:
    """An opened sequence.

    path: the sequence folder; calibration: intrinsics (left, optional right);
    handeye: nominal camera-from-base 4x4 (METRES); robot: what the robot loader
    returned for robot.json; labels: {frame: (u, v) px} from labels.csv, or None;
    labels_right: the same from labels_right.csv (right raw image), or None;
    n_joints: the DH joint count every reading must have (None: not checked);
    source: the BagSource or FolderSource behind the frames.
    """

    path: Path
    calibration: Calibration
    handeye: np.ndarray
    robot: object
    labels: dict[int, np.ndarray] | None
    n_joints: int | None
    source: BagSource | FolderSource
    notes: list[str] = field(default_factory=list)
    labels_right: dict[int, np.ndarray] | None = None
    #: frames whose right image right_problem() refused, by reason (image_size, same_as_left)
    right_refused: dict[str, int] = field(default_factory=lambda: {"image_size": 0, "same_as_left": 0})

    def __len__(self) -> int:
        return len(self.source)

    @property
    def warnings(self) -> list[str]:
        """Lines for the user: recording choices made, damage found, messages skipped
        (including, after iterating, the frames whose right image was unusable)."""
        lines = self.notes + list(self.source.warnings)
        if self.right_skip_warning:
            lines.append(self.right_skip_warning)
        return lines

    @property
    def right_skip_warning(self) -> str | None:
        """The line for the user on the frames yielded so far without a usable right image."""
        sk = self.right_skips
        if not sum(sk.values()):
            return None
        copy = (": a right image identical to its left one is a copy of it, and frames_right/ (or the right "
                "image topic) must hold the right camera's images" if sk.get("same_as_left") else "")
        return (f"{self.path}: {sum(sk.values())} frames without a usable right image "
                f"({', '.join(f'{k} {v}' for k, v in sk.items() if v)}); left-only for those{copy}")

    @property
    def stereo(self) -> bool:
        """True when the recording has right images and the right camera's calibration."""
        return self.has_right_images and self.calibration.right is not None

    @property
    def has_right_images(self) -> bool:
        src = self.source
        return (src.right_files is not None) if isinstance(src, FolderSource) else src.right_topic is not None

    @property
    def right_skips(self) -> dict[str, int]:
        """Frames yielded so far with image_right None although the recording is stereo:
        {"missing": no right image within the stamp tolerance / no file, "corrupt": does not
        decode, "image_size": differs from ImageSize, "same_as_left": identical to the left
        image, a copy of it (no stereo rig gives two identical images)}."""
        return {**self.source.right_skips, **self.right_refused}

    @property
    def kind(self) -> str:
        """``"bag"`` (ROS 1), ``"ros2"`` or ``"folder"``."""
        if isinstance(self.source, FolderSource):
            return "folder"
        return "ros2" if self.source.ros2 else "bag"

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width) px of the raw images, from camera_calibration.yaml."""
        cam = self.calibration.left
        return int(cam.height), int(cam.width)

    @property
    def has_jaw(self) -> bool:
        """True when the recording carries jaw readings (else every Frame.jaw is NaN)."""
        return bool(self.source.has_jaw)

    @property
    def uses_jaw(self) -> bool:
        """True when the jaw readings are used: the recording carries them and robot.json's
        tool has jaws (a jawless tool's are ignored: every Frame.jaw is NaN; the recording's
        notes say so, :func:`graphtrack.io.consistency.consistency_notes`)."""
        return self.has_jaw and bool(getattr(self.robot, "has_gripper", True))

    @property
    def truncated(self) -> bool:
        """True when the bag was damaged and read only up to the damage."""
        return bool(self.source.truncated)

    @property
    def stamps(self) -> np.ndarray:
        """Frame stamps (s). Free for folders; one pass over the image messages for bags."""
        return self.source.stamps()

    def __iter__(self) -> Iterator[object]:
        return self.frames()

    def _check_bag_units(self, bounds) -> None:
        """InputError when most joint (or jaw) messages of the bag are beyond their bounds
        (:func:`graphtrack.io.joint_units.check_table`)."""
        src = self.source
        joints, jaw = src.joint_tables()
        check_table(joints.values, np.zeros(len(joints.values)), bounds, False, f"{src.path}: {src.joint_topic}",
                    "messages", "message")
        if self.uses_jaw and bounds is not None and jaw.values.shape[1]:   # no column: every jaw message empty
            check_table(np.zeros((len(jaw.values), 0)), jaw.values[:, 0], np.zeros(0), True,
                        f"{src.path}: {src.jaw_topic}", "messages", "message")

    def frames(self, start: int = 0, expected_joints: int | None = None,
               right: bool = True) -> Iterator[object]:
        """Yield a :class:`~graphtrack.estimate.base.Frame` or a FrameError per frame, in order.

        start: first frame index to yield (earlier images are skipped undecoded);
        expected_joints: DH joint count to enforce (default: ``self.n_joints``);
        right: False leaves a stereo recording's right images unread (a mono run).
        """
        n_exp = self.n_joints if expected_joints is None else int(expected_joints)
        h, w = self.image_size
        has_jaw = self.uses_jaw
        bounds = joint_bounds(self.robot, n_exp)
        if isinstance(self.source, BagSource) and start == 0:
            self._check_bag_units(bounds)
        for item in self.source.frames(start, right=right):
            if isinstance(item, FrameError):
                yield item
                continue
            if not has_jaw:
                item.jaw = float("nan")   # Frame.q: the DH joints alone
            problem = frame_problem(item, n_exp, (h, w), bounds, has_jaw)
            if problem is not None:
                yield problem
                continue
            why = right_problem(item, (h, w))
            if why is not None:
                item.image_right = None
                self.right_refused[why] = self.right_refused.get(why, 0) + 1
            yield item


def _dh_count(robot_json: Path) -> int | None:
    doc = read_json(robot_json)
    dh = doc.get("DH_params") if isinstance(doc, dict) else None
    return len(dh) if isinstance(dh, list) and dh else None


def _default_robot_loader(path: Path):
    return load_robot_json(path)


def find_source(path: Path, topics: TopicSelection = TopicSelection()) -> tuple[BagSource | FolderSource, list[str]]:
    """Pick the recording in a sequence folder: exactly one bag, else the folder form."""
    bags = sorted(p for p in path.iterdir() if p.suffix == ".bag" and p.is_file())
    bags += sorted(p for p in path.iterdir() if is_ros2_bag(p))
    if not bags and is_ros2_bag(path):   # `ros2 bag record -o SEQ`, the other files added beside it
        bags = [path]
    if not bags:  # a recording killed before rosbag renamed it: salvaged by scanning
        bags = sorted(p for p in path.glob("*.bag.active") if p.is_file())
    folder_form = (path / "frames").is_dir() or (path / "video.mp4").is_file()
    notes: list[str] = []
    if len(bags) == 1:
        if folder_form:
            notes.append(f"{path}: both {bags[0].name} and frames/ or video.mp4; using the bag")
        return BagSource(bags[0], topics), notes
    if folder_form:
        if bags:
            notes.append(f"{path}: {len(bags)} bags; using the folder form (frames/ or video.mp4)")
        return FolderSource(path), notes
    if not bags:
        _no_metadata(path)
        raise InputError(f"{path}: no recording: no .bag file (nor ROS 2 bag folder) and no "
                         "frames/ or video.mp4 with joints.csv")
    raise InputError(f"{path}: {len(bags)} bags ({', '.join(b.name for b in bags)}); "
                     "a sequence holds exactly one (parts of a `rosbag record --split` recording? merge them "
                     "into one bag, or track each part in a sequence folder of its own)")


def open_recording(path: str | Path, robot_loader: Callable[[Path], object] | None = None,
                   expected_joints: int | None = None, topics: TopicSelection = TopicSelection()) -> Recording:
    """Open and validate a sequence folder; no image is read.

    Parameters
    ----------
    path : the sequence folder.
    robot_loader : called with the robot.json path; default
        ``graphtrack.robot.description.load_robot_json``.
    expected_joints : DH joints per reading; default: ``robot.n_dh``, else the
        number of ``DH_params`` in robot.json.
    topics : the arm (its joint topics and handeye.yaml keys) and topic overrides; by
        default the arm is the bag's only arm (the folder form: handeye.yaml's only arm),
        the topics follow the dVRK 1.x or 2.x naming the bag uses
        (:mod:`graphtrack.io.topics`).

    Raises InputError (one line naming the file / topic / field) for
    whole-recording problems; see the module docstring.
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{path}: not a folder (a sequence is a folder holding {', '.join(REQUIRED)} "
                         "and a bag or frames/)")
    for name in REQUIRED:
        if not (path / name).is_file():
            raise InputError(f"{path / name}: file not found (every sequence needs {', '.join(REQUIRED)})")
    robot = (robot_loader or _default_robot_loader)(path / "robot.json")
    n_joints = expected_joints
    if n_joints is None:
        n_dh = getattr(robot, "n_dh", None)
        n_joints = int(n_dh) if isinstance(n_dh, (int, np.integer)) else _dh_count(path / "robot.json")
    calibration = load_calibration(path / "camera_calibration.yaml")
    size = (calibration.left.height, calibration.left.width)
    size_from = f"ImageSize in {path / 'camera_calibration.yaml'}"
    labels, labels_r = (read_labels(path / name, size, size_from) if (path / name).exists() else None
                        for name in ("labels.csv", "labels_right.csv"))
    source, notes = find_source(path, topics)
    given = [f"--{k}-topic" for k in ("image", "joint", "jaw") if getattr(topics, k) is not None]
    given += ["--right-image-topic"] if topics.right is not None else []
    given += ["--max-joint-gap"] if topics.joint_gap is not None else []
    if isinstance(source, FolderSource) and given:
        notes.append(f"{path}: {', '.join(given)} ignored: they are for bags, and this recording is the "
                     "folder form (frames/ or video.mp4 with joints.csv)")
    handeye = load_handeye(path / "handeye.yaml", getattr(source, "arm", None) or topics.arm)
    if isinstance(source, FolderSource):
        check_table(*source.readings(), joint_bounds(robot, n_joints), source.has_jaw, path / "joints.csv")
    if isinstance(source, FolderSource) and n_joints is not None and source.n_columns != n_joints:
        raise InputError(f"{path / 'joints.csv'}: rows hold {source.n_columns} joints (q1..q{source.n_columns}) "
                         f"but {path / 'robot.json'} has {n_joints} DH joints")
    rec = Recording(path, calibration, handeye, robot, labels, n_joints, source,
                    notes=notes, labels_right=labels_r)
    rec.notes += consistency_notes(rec)
    return rec


def _no_metadata(path: Path) -> None:
    """InputError naming a ROS 2 bag's storage (.db3, .mcap) in ``path`` or a folder of it
    without its metadata.yaml: what a killed ``ros2 bag record`` leaves."""
    for folder in [path, *sorted(p for p in path.iterdir() if p.is_dir())]:
        storage = sorted(q.name for q in folder.iterdir() if q.suffix in (".db3", ".mcap") and q.is_file())
        if storage and not (folder / "metadata.yaml").exists():
            raise InputError(f"{folder}: ROS 2 bag storage ({', '.join(storage[:3])}) without metadata.yaml, "
                             f"which `ros2 bag record` writes when it stops (was it killed?): rebuild it with "
                             f"`ros2 bag reindex {folder}`")


def is_ros2_bag(folder: Path) -> bool:
    """A ROS 2 bag is a folder holding metadata.yaml (and its storage files)."""
    return folder.is_dir() and (folder / "metadata.yaml").is_file()


def part_of_recording(folder: Path) -> bool:
    """A recording's own sub-folders: frames/, frames_right/, a ROS 2 bag."""
    return folder.name in ("frames", "frames_right") or is_ros2_bag(folder)


def same_recording(stored: dict, path: str | Path) -> bool:
    """Whether a fingerprint stored earlier (perhaps with other folders in it, as before
    those were left out) still describes the recording at ``path``."""
    stored = {k: v for k, v in stored.items() if not k.endswith("/") or part_of_recording(Path(path) / k[:-1])}
    return stored == fingerprint(path)


def fingerprint(path: str | Path) -> dict[str, list[int]]:
    """What identifies a recording folder's content cheaply, to tell a changed recording
    from the one a result was computed on: per top-level file its [size, mtime ns], per
    folder of the recording (frames/, frames_right/, a ROS 2 bag) the count, total size and
    latest mtime of its files. Other folders (a run's output kept beside the recording,
    even the study itself) are not part of it. No file is read."""
    out: dict[str, list[int]] = {}
    for p in sorted(Path(path).iterdir()):
        try:
            if p.is_file():
                st = p.stat()
                out[p.name] = [st.st_size, st.st_mtime_ns]
            elif p.is_dir() and part_of_recording(p):
                sts = [q.stat() for q in p.iterdir() if q.is_file()]
                out[p.name + "/"] = [len(sts), sum(s.st_size for s in sts), max((s.st_mtime_ns for s in sts), default=0)]
        except OSError:
            out[p.name] = [-1, -1]
    return out
