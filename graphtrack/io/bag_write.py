"""Writing a ROS 1 bag in the sequence format (format doc, "The bag"): the
simulator's output and the tests' recordings; :mod:`graphtrack.io.bag` reads it."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable, Sequence

import cv2
import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

from graphtrack.io.bag import (COMPRESSED_TOPIC, IMAGE_TOPIC, JOINT_TYPE, RIGHT_COMPRESSED_TOPIC,
                               RIGHT_IMAGE_TOPIC)
from graphtrack.io.bag_stamps import to_ns
from graphtrack.io.image_msg import COMPRESSED_TYPE, IMAGE_TYPE
from graphtrack.io.joint_names import DVRK_PSM_JOINTS
from graphtrack.io.topics import jaw_topics, joint_topics


def write_bag(path: str | Path, frames: Iterable, compressed: bool = False, image_format: str = "png",
              arm: str = "PSM1", chunk_compression: str | None = None, dvrk_version: int = 1,
              joint_names: Sequence[str] | None = None) -> int:
    """Write a ROS 1 bag in the sequence format, streaming (one frame in memory at a time).

    Parameters
    ----------
    path : the ``.bag`` file to create (must not exist).
    frames : iterable of objects with ``stamp`` (s), ``image`` (H x W x 3 uint8 BGR),
        ``joints`` (n,) rad/m and ``jaw`` (rad, NaN = no gripper: no jaw message), and
        optionally ``image_right`` (not None: a message on the right topic, same stamp).
    compressed : write ``/stereo/left/image/compressed`` (CompressedImage, ``image_format``
        "png" or "jpeg") instead of raw ``rgb8`` Images on ``/stereo/left/image``.
    chunk_compression : None, "bz2" or "lz4" (bag-level compression).
    arm, dvrk_version : the joint and jaw topics: ``/dvrk/<arm>/state_joint_current`` and
        ``/dvrk/<arm>/state_jaw_current`` (1), or ``/<arm>/measured_js`` and
        ``/<arm>/jaw/measured_js`` (2).
    joint_names : the joint messages' ``name[]``, each a dVRK PSM joint name
        (:data:`graphtrack.io.joint_names.DVRK_PSM_JOINTS`) in any order, the values
        written in that order; None: no names, the values in DH order.

    Every message's header stamp and bag record time is the frame's stamp.
    Returns the number of frames written.
    """
    if dvrk_version not in (1, 2):
        raise ValueError(f"dvrk_version must be 1 or 2, got {dvrk_version!r}")
    joint_topic, jaw_topic = joint_topics(arm)[dvrk_version - 1], jaw_topics(arm)[dvrk_version - 1]
    names = list(joint_names or [])
    # the values in the names' order (ValueError for a name the PSM has not); all, unnamed
    order = [DVRK_PSM_JOINTS.index(n) for n in names] or slice(None)
    if image_format not in ("png", "jpeg", "jpg"):
        raise ValueError(f"image_format must be png or jpeg, got {image_format!r}")
    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    ext = ".png" if image_format == "png" else ".jpg"
    writer = Writer(Path(path))
    if chunk_compression:
        writer.set_compression(Writer.CompressionFormat[chunk_compression.upper()])
    n = 0
    with writer:
        img_type = COMPRESSED_TYPE if compressed else IMAGE_TYPE
        c_img = writer.add_connection(COMPRESSED_TOPIC if compressed else IMAGE_TOPIC, img_type, typestore=ts)
        c_joint = writer.add_connection(joint_topic, JOINT_TYPE, typestore=ts)
        c_jaw = c_right = None
        for f in frames:
            t = to_ns(float(f.stamp))
            if t < 0:
                raise ValueError(f"frame {n}: negative stamp {f.stamp}")
            hdr = T["std_msgs/msg/Header"](seq=n, stamp=T["builtin_interfaces/msg/Time"](
                sec=t // 1_000_000_000, nanosec=t % 1_000_000_000), frame_id="left")
            msg = _image_msg(T, hdr, f.image, compressed, ext, n)
            writer.write(c_img, t, ts.serialize_ros1(msg, img_type))
            right = getattr(f, "image_right", None)
            if right is not None:
                if c_right is None:
                    c_right = writer.add_connection(RIGHT_COMPRESSED_TOPIC if compressed else RIGHT_IMAGE_TOPIC,
                                                    img_type, typestore=ts)
                hdr_r = T["std_msgs/msg/Header"](seq=n, stamp=hdr.stamp, frame_id="right")
                writer.write(c_right, t, ts.serialize_ros1(_image_msg(T, hdr_r, right, compressed, ext, n), img_type))
            writer.write(c_joint, t, ts.serialize_ros1(_joint_state(T, hdr, np.asarray(f.joints)[order], names), JOINT_TYPE))
            jaw = float(getattr(f, "jaw", float("nan")))
            if math.isfinite(jaw):
                if c_jaw is None:
                    c_jaw = writer.add_connection(jaw_topic, JOINT_TYPE, typestore=ts)
                writer.write(c_jaw, t, ts.serialize_ros1(_joint_state(T, hdr, [jaw]), JOINT_TYPE))
            n += 1
    return n


def _image_msg(T, hdr, image, compressed: bool, ext: str, n: int):
    img = np.ascontiguousarray(image, dtype=np.uint8)
    if compressed:
        ok, buf = cv2.imencode(ext, img)
        if not ok:
            raise ValueError(f"frame {n}: cv2.imencode({ext}) failed")
        return T[COMPRESSED_TYPE](header=hdr, format="png" if ext == ".png" else "jpeg", data=buf.ravel())
    mono = img.ndim == 2
    data = img if mono else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return T[IMAGE_TYPE](header=hdr, height=img.shape[0], width=img.shape[1],
                         encoding="mono8" if mono else "rgb8", is_bigendian=0,
                         step=img.shape[1] * (1 if mono else 3), data=data.ravel())


def _joint_state(T, hdr, position, names=()) -> object:
    empty = np.zeros(0, dtype=np.float64)
    return T[JOINT_TYPE](header=hdr, name=list(names), position=np.asarray(position, dtype=np.float64).ravel(),
                         velocity=empty, effort=empty)
