"""The plain-folder form of a sequence (format doc, "The plain folder form").

::

    frames/000000.png, frames/000001.png, ...   (or video.mp4): the raw left images
    joints.csv   header  frame,stamp,q1,...,qn,jaw   one row per frame (or the dVRK PSM's
                 joint names for q1..q6, any order)
    frames_right/000000.png, ...                  (stereo, optional): the raw right images

``frame`` is the 0-based frame number and must equal the row number; ``stamp``
is in seconds; ``q1..qn`` are the DH joints (rad / m); ``jaw`` is the jaw
opening (rad), empty or ``nan`` for tools without a gripper. Frame k's image
is ``frames/<k>.<ext>`` with k zero-padded to 6 digits (any image extension
OpenCV reads), or the k-th frame of ``video.mp4``. Images are read one at a
time; a video is decoded sequentially with ``cv2.VideoCapture``.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from graphtrack.errors import FrameError, InputError, read_text
from graphtrack.io.decode import read_image_file
from graphtrack.io.frame import Frame
from graphtrack.io.joint_names import DVRK_PSM_JOINTS, missing_and_repeated, name_order
from graphtrack.io.stamps import median_interval
from graphtrack.io.video import open_video, still_image

#: why a video.mp4 that FFmpeg cannot open is refused
UNOPENABLE_VIDEO = "cannot open the video (damaged, cut short, or not a video FFmpeg decodes)"
IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
#: s: the most the median interval between frames may be (the motion model's frame to frame)
MAX_FRAME_INTERVAL_S = 10.0
#: s: a median interval above this (under one frame per second) is warned about: milliseconds
#: of a camera at 100 frames/s or more read as seconds, below MAX_FRAME_INTERVAL_S
SLOW_FRAME_INTERVAL_S = 1.0


def read_joints_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """joints.csv -> (stamps (N,) s, joints (N, n), jaw (N,) NaN when empty).

    Raises InputError naming the file (and line) on a wrong header, a wrong
    field count, a non-number, a ``frame`` that is not the row number, a
    stamp that is empty, not finite or not after the previous row's, or stamps
    whose median interval exceeds ``MAX_FRAME_INTERVAL_S`` (not seconds).
    """
    try:
        out = _parse_joints_csv(read_text(path), path)
    except csv.Error as e:
        raise InputError(f"{path}: not a readable CSV file ({e})") from None
    if not len(out[0]):
        raise InputError(f"{path}: no rows after the header (one row per frame: frame, stamp, the joints, jaw)")
    step = median_interval(out[0])
    if step > MAX_FRAME_INTERVAL_S:
        raise InputError(f"{path}: the stamps are {step:.6g} apart (median); stamps are seconds, and frames "
                         f"more than {MAX_FRAME_INTERVAL_S:g} s apart are no video (milliseconds or nanoseconds?)")
    return out


def _csv_number(text: str, column: str, path: Path, line: int) -> float:
    """One joints.csv value: a plain decimal number (NaN when empty). Python's float() also
    takes '1_000' and non-ASCII digits, which no CSV writer means as numbers: refused too."""
    t = text.strip()
    if not t:
        return math.nan
    try:
        if not t.isascii() or "_" in t:
            raise ValueError
        return float(t)
    except ValueError:
        hint = (" (a decimal comma? write 0.5, not 0,5)" if "," in t else
                " (stamps are seconds, a number, not a date)" if column == "stamp" else "")
        raise InputError(f"{path}: line {line}: {column} {t!r} is not a number{hint}") from None


def _csv_int(text: str, path: Path, line: int) -> int:
    t = text.strip()
    if not (t.isascii() and t.isdigit()):
        raise InputError(f"{path}: line {line}: frame {t!r} is not a whole number (frames are 0, 1, 2, ...)")
    return int(t)


def _joint_columns(header: list[str], path: Path) -> np.ndarray | None:
    """The joint columns of a joints.csv header: q1..qn in DH order (None), or the dVRK PSM's
    joint names in any order (the indices that put them in DH order); InputError otherwise."""
    n = len(header) - 3
    names = header[2:-1]
    if n >= 1 and header[:2] == ["frame", "stamp"] and header[-1] == "jaw":
        if names == [f"q{i}" for i in range(1, n + 1)]:
            return None
        if sorted(names) == sorted(DVRK_PSM_JOINTS):
            return name_order(names, str(path))   # None when already in DH order
    raise InputError(f"{path}: header must be 'frame,stamp,q1,...,qn,jaw' (or the dVRK PSM's joint names for "
                     f"q1..q6, in any order), found {','.join(header)!r}{_names_hint(header)}")


def _names_hint(header: list[str]) -> str:
    """What a joints.csv header that uses the dVRK's joint names gets wrong ("" without them)."""
    if not any(h in DVRK_PSM_JOINTS for h in header):
        return ""
    missing, twice = missing_and_repeated(header)
    wrong = ([f"missing: {', '.join(missing)}"] if missing else []) + ([f"twice: {', '.join(twice)}"] if twice else [])
    if wrong:
        return f"; with the dVRK's joint names give each of the six once ({'; '.join(wrong)})"
    return "; the six joint names go between stamp and jaw, and jaw is the last column"


def _parse_joints_csv(text: str, path: Path):
    reader = csv.reader(text.splitlines())
    header = [h.strip() for h in next(reader, [])]
    n = len(header) - 3
    order = _joint_columns(header, path)
    stamps, joints, jaw, prev_line = [], [], [], 1
    for line, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            comma = " (a decimal comma? write 0.5, not 0,5)" if len(row) > len(header) else ""
            raise InputError(f"{path}: line {line} has {len(row)} fields, expected {len(header)}{comma}")
        frame = _csv_int(row[0], path, line)
        vals = [_csv_number(v, name, path, line) for v, name in zip(row[1:], header[1:])]
        if frame != len(stamps):
            raise InputError(f"{path}: line {line}: frame {frame}, expected {len(stamps)} "
                             "(frames must be 0, 1, 2, ... in order)")
        if not math.isfinite(vals[0]):
            raise InputError(f"{path}: line {line}: stamp {row[1].strip()!r} is not a finite number of seconds")
        if stamps and not vals[0] > stamps[-1]:
            raise InputError(f"{path}: line {line}: stamp {vals[0]!r} is not after line {prev_line}'s "
                             f"{stamps[-1]!r} (stamps must increase)")
        prev_line = line
        stamps.append(vals[0])
        joints.append(vals[1:-1])
        jaw.append(vals[-1])
    joints = np.array(joints, dtype=float).reshape(-1, n)
    return np.array(stamps, dtype=float), joints if order is None else joints[:, order], np.array(jaw, dtype=float)


def _one_based(files: dict, n_rows: int) -> bool:
    """Images numbered 1..n for frames 0..n-1 (k+1 for frame k)."""
    return bool(files) and 0 not in files and len(files) == n_rows and max(files) == n_rows


def _check_numbering(folder: Path, files: dict, n_rows: int) -> None:
    """InputError when ``folder`` holds an image numbered beyond joints.csv's rows (frame k
    is row k: images are never re-paired), saying so when they are numbered from 1."""
    extra = sorted(k for k in files if k >= n_rows)
    if not extra:
        return
    hint = ("; the images are numbered from 1, frames from 0: rename them (000001.png -> 000000.png, "
            "...) so that image k is joints.csv's row of frame k" if _one_based(files, n_rows) else "")
    raise InputError(f"{folder}: holds {len(files)} images but joints.csv has {n_rows} rows (first image "
                     f"without a row: {files[extra[0]].name}); every image needs its own row, images are "
                     f"never re-paired{hint}")


class FolderSource:
    """frames/ (or video.mp4) + joints.csv; validated at construction, streamed later.

    Attributes: path, n_images (= rows of joints.csv), n_columns (joints per row),
    has_jaw, truncated (False), warnings.
    """

    def __init__(self, root: str | Path):
        self.path = Path(root)
        self.truncated = False
        self.warnings: list[str] = []
        self._stamps, self._joints, self._jaw = read_joints_csv(self.path / "joints.csv")
        self.n_images = len(self._stamps)
        step = median_interval(self._stamps)
        if step > SLOW_FRAME_INTERVAL_S:
            self.warnings.append(f"{self.path / 'joints.csv'}: the stamps are {step:.4g} s apart (median), under one "
                                 "frame per second; milliseconds (a camera at 100 frames/s or more) must be divided "
                                 "by 1000: the smoother's lag and the edge bias's time constant are seconds")
        self.n_columns = self._joints.shape[1]
        self.has_jaw = bool(np.any(np.isfinite(self._jaw)))
        frames_dir = self.path / "frames"
        self.video, self.video_frames = None, 0   # video.mp4 and the frame count its container lists
        self._files: dict[int, Path] = {}
        right_dir = self.path / "frames_right"
        #: frame -> right image file (frames_right/, same names as frames/); None: mono
        self.right_files = _image_files(right_dir) if right_dir.is_dir() else None
        self.right_skips = {"missing": 0, "corrupt": 0}
        if self.right_files:
            self._check_right_numbering(right_dir)
        if frames_dir.is_dir():
            self._files = _image_files(frames_dir)
            if self.n_images and not self._files:
                raise InputError(f"{frames_dir}: no images")
            _check_numbering(frames_dir, self._files, self.n_images)
            if (self.path / "video.mp4").exists():
                self.warnings.append(f"{self.path / 'video.mp4'}: not read: frames/ holds the images (a "
                                     "recording has one or the other)")
            missing = self.n_images - len(self._files)
            if missing and len(self._files) == max(self._files) + 1 and self.n_images >= 1.5 * len(self._files):
                self.warnings.append(   # images 0..m-1 and rows far beyond: a joint log at its own rate?
                    f"{self.path / 'joints.csv'}: {self.n_images} rows for {len(self._files)} images (frames/ "
                    f"0-{max(self._files)}, {1.0 / step:.0f} rows/s): row k is image k's reading; a joint log "
                    "recorded at its own rate must be resampled to the image stamps (one row per image), or "
                    f"every frame gets another moment's joints; the {missing} rows without an image are skipped")
            elif missing:
                self.warnings.append(f"{frames_dir}: {missing} of {self.n_images} frames have no image")
        elif (self.path / "video.mp4").is_file():
            self.video = self.path / "video.mp4"
            self._check_video_length()
        else:
            raise InputError(f"{self.path}: neither frames/ nor video.mp4 holds the images")

    def _check_right_numbering(self, right_dir: Path) -> None:
        """frames_right/ numbered from 1 would pair each right image with the wrong frame: not
        used (left-only), with a warning; right images beyond joints.csv's rows are unused,
        with a note (the right images are optional, and unread with --mono)."""
        files, n = self.right_files, self.n_images
        extra = sorted(k for k in files if k >= n)
        if _one_based(files, n):
            self.right_files = None
            self.warnings.append(f"{right_dir}: the right images are numbered 1..{n} for frames 0..{n - 1}: each "
                                 "would pair with the wrong frame, so they are not used (left-only); rename "
                                 "them from 000000")
        elif extra:
            self.warnings.append(f"{right_dir}: {len(extra)} right images beyond joints.csv's {n} rows (first: "
                                 f"{files[extra[0]].name}) are not used")

    def __len__(self) -> int:
        return int(self.n_images)

    def _check_video_length(self) -> None:
        """InputError when video.mp4 does not open, or holds more frames than joints.csv has
        rows (the container's frame count): as with frames/, frames are never re-paired."""
        cap = open_video(self.video)
        opened = cap.isOpened()
        n = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0) if opened else 0   # < 0: not listed
        still = still_image(self.video, cap) if opened and n <= 1 else None
        cap.release()
        if not opened:   # here, before a run writes anything: not at its first frame
            raise InputError(f"{self.video}: {UNOPENABLE_VIDEO}")
        if still:
            raise InputError(f"{self.video}: one {still} image, not a video: put the images in frames/ "
                             f"(frames/000000.{still.lower().replace('jpeg', 'jpg')}, ...) or encode them as video.mp4")
        self.video_frames = n
        if n > self.n_images:
            raise InputError(f"{self.video}: holds {n} frames but joints.csv has {self.n_images} rows "
                             f"(first frame without a row: {self.n_images}); every frame needs its own row, "
                             "frames are never re-paired")

    def readings(self) -> tuple[np.ndarray, np.ndarray]:
        """(joints (N, n), jaw (N,)) of joints.csv, as read (NaN where empty)."""
        return self._joints, self._jaw

    def stamps(self) -> np.ndarray:
        """Frame stamps (s) from joints.csv."""
        return self._stamps.copy()

    def _images(self, start: int):
        """Yield (index, BGR image or the FrameError of a missing or corrupt one) from ``start`` on."""
        if self.video is None:
            for k in range(start, self.n_images):
                p = self._files.get(k)
                if p is None:
                    yield k, FrameError(k, "missing_image", f"no image file frames/{k:06d}.* (missing)")
                    continue
                img, why = read_image_file(p)
                yield k, (img if why is None else FrameError(k, "corrupt_image", why))
            return
        cap = open_video(self.video)
        if not cap.isOpened():
            raise InputError(f"{self.video}: {UNOPENABLE_VIDEO}")   # opened before, not now
        try:
            ended = False
            for k in range(start):
                if not cap.grab():
                    ended = True
                    break
            for k in range(start, self.n_images):
                ok, img = (False, None) if ended else cap.read()
                if ok:
                    yield k, img
                    continue
                why = f"{self.video.name} ended before frame {k}" if ended else self._ended(k)
                ended = True
                yield k, FrameError(k, "video_ended", why)
        finally:
            cap.release()

    def _ended(self, k: int) -> str:
        """Why frame k and the rest have no image: the video ends (its container lists k
        frames or fewer) or stopped decoding at k (damaged; the later frames are not read, so
        that none pairs with another row)."""
        rest = f"frame {k} has" if k == self.n_images - 1 else f"frames {k}-{self.n_images - 1} have"
        listed = self.video_frames
        if k < listed:
            return (f"{self.video.name} stopped decoding at frame {k} of the {listed} its container lists "
                    f"(damaged?): {rest} no image")
        return f"{self.video.name} ends after {k} frames and joints.csv has {self.n_images} rows: {rest} no image"

    def _right(self, k: int):
        """frames_right/<k>: the image, or None (missing / not decodable: counted in right_skips)."""
        if self.right_files is None:
            return None
        p = self.right_files.get(k)
        img = read_image_file(p)[0] if p is not None else None
        if img is None:
            self.right_skips["missing" if p is None else "corrupt"] += 1
        return img

    def frames(self, start: int = 0, right: bool = True):
        """Yield, per row of joints.csv from ``start`` on, a Frame (unchecked) or a FrameError.

        Frame.image_right: frames_right/ holds the right image of the left image with the
        same name (same row, same stamp); None when it is missing or does not decode, or
        unread with ``right`` False."""
        for k, img in self._images(start):
            if isinstance(img, FrameError):
                yield img
            else:
                yield Frame(k, float(self._stamps[k]), img, self._joints[k].copy(), float(self._jaw[k]),
                            image_right=self._right(k) if right else None)


def _image_files(d: Path) -> dict[int, Path]:
    """{frame: file} of the images in a frames folder; InputError on a bad or repeated name."""
    out: dict[int, Path] = {}
    for p in d.iterdir():
        if p.name.startswith(".") or p.suffix.lower() not in IMAGE_EXTS:
            continue
        if not p.stem.isdigit():
            raise InputError(f"{p}: image names in {d.name}/ must be frame numbers (000000.png)")
        if int(p.stem) in out:
            raise InputError(f"{p}: frame {int(p.stem)} has two images in {d}")
        out[int(p.stem)] = p
    return out


def write_folder(out_dir: str | Path, frames: Iterable, video: bool = False, fps: float = 30.0,
                 image_ext: str = "png") -> int:
    """Write the plain-folder form, streaming: frames/NNNNNN.<ext> (or video.mp4) + joints.csv.

    ``frames``: objects with stamp (s), image (H x W x 3 uint8 BGR), joints (n,)
    and jaw (rad or NaN); an ``image_right`` that is not None goes to
    frames_right/ under the same name. joints.csv is flushed after every row.
    ``video=True`` writes an mp4v-coded video.mp4 (lossy) instead of the left image files.
    Returns the number of frames written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if not video:
        (out / "frames").mkdir(exist_ok=True)
    right_dir = None
    writer, n, width = None, 0, None
    with (out / "joints.csv").open("w", newline="") as f:
        try:
            for fr in frames:
                q = np.asarray(fr.joints, dtype=float).ravel()
                if width is None:
                    width = q.size
                    f.write(",".join(["frame", "stamp"] + [f"q{i}" for i in range(1, width + 1)] + ["jaw"]) + "\n")
                elif q.size != width:
                    raise ValueError(f"frame {n}: {q.size} joints, earlier frames had {width}")
                img = np.ascontiguousarray(fr.image, dtype=np.uint8)
                if video:
                    if writer is None:
                        writer = cv2.VideoWriter(str(out / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                                                 float(fps), (img.shape[1], img.shape[0]))
                        if not writer.isOpened():
                            raise ValueError(f"{out / 'video.mp4'}: OpenCV cannot write mp4v video")
                    writer.write(img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
                elif not cv2.imwrite(str(out / "frames" / f"{n:06d}.{image_ext}"), img):
                    raise ValueError(f"frame {n}: cv2.imwrite failed")
                right = getattr(fr, "image_right", None)
                if right is not None:
                    if right_dir is None:
                        right_dir = out / "frames_right"
                        right_dir.mkdir(exist_ok=True)
                    if not cv2.imwrite(str(right_dir / f"{n:06d}.{image_ext}"), np.ascontiguousarray(right)):
                        raise ValueError(f"frame {n}: cv2.imwrite (right) failed")
                jaw = float(getattr(fr, "jaw", math.nan))
                f.write(",".join([str(n), repr(float(fr.stamp))] + [repr(float(v)) for v in q]
                                 + [repr(jaw) if math.isfinite(jaw) else "nan"]) + "\n")
                f.flush()
                n += 1
        finally:
            if writer is not None:
                writer.release()
    return n
