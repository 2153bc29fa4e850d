"""Arguments shared by the commands that read a recording (the arm, topics, threads) and
the help formatter every command uses."""
from __future__ import annotations

import argparse
import math

from graphtrack.errors import InputError
from graphtrack.io.topics import ARMS, TopicSelection
from graphtrack.threads import DEFAULT_THREADS


class HelpFormatter(argparse.HelpFormatter):
    """``--help`` that states every option's default: ``(default: X)`` after the help text,
    ``(default: off)`` for an on/off flag, nothing for a required option, and the help's own
    words where it already says ``default:`` (an option whose default is computed, e.g. "all")."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (not action.option_strings or action.required or "default:" in text
                or action.default is argparse.SUPPRESS):
            return text
        if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._StoreConstAction)):
            return text + " (default: off)"
        return text + " (default: %(default)s)"


def mm_deg(text: str | None, option: str) -> tuple[float, float] | None:
    """An option's "MM,DEG" (a translation and a rotation, e.g. "10,4") as (m, rad); None
    when not given; InputError naming ``option`` for anything else."""
    if text is None:
        return None
    try:
        mm, deg = (float(v) for v in str(text).replace(" ", "").split(","))
    except ValueError:
        raise InputError(f"{option} takes MM,DEG (two numbers, e.g. 10,4), got {text!r}") from None
    return mm * 1e-3, math.radians(deg)


def output_path(value: str) -> str:
    """argparse ``type`` of an output path: an empty one (``--out ''``, which would
    silently mean the current folder) is refused."""
    if not value.strip():
        raise argparse.ArgumentTypeError("an empty path would mean the current folder: name the output")
    return value


def add_source_arguments(p) -> None:
    """--arm and the topic overrides (bag recordings; the folder form reads only --arm)."""
    g = p.add_argument_group("recording")
    g.add_argument("--arm", choices=ARMS, default=None,
                   help="the tracked arm: its joint topics and handeye.yaml keys (default: the recording's only arm)")
    g.add_argument("--image-topic", metavar="TOPIC", default=None,
                   help="left image topic (default: /stereo/left/image, else /stereo/left/image/compressed)")
    g.add_argument("--joint-topic", metavar="TOPIC", default=None,
                   help="joint topic (default: /dvrk/ARM/state_joint_current, or dVRK 2.x /ARM/measured_js)")
    g.add_argument("--jaw-topic", metavar="TOPIC", default=None,
                   help="jaw topic (default: /dvrk/ARM/state_jaw_current, or dVRK 2.x /ARM/jaw/measured_js)")
    g.add_argument("--right-image-topic", metavar="TOPIC", default=None,
                   help="stereo right image topic (default: the --image-topic with left -> right, else "
                        "/stereo/right/image or /stereo/right/image/compressed)")
    g.add_argument("--max-joint-gap", type=float, metavar="S", default=None,
                   help="a frame whose nearest joint (or jaw) reading is more than S seconds from its image is "
                        "skipped (default: 0.2, or 3 median periods of a slower joint topic)")


def source_from_args(args) -> TopicSelection:
    return TopicSelection(arm=args.arm, image=args.image_topic, joint=args.joint_topic, jaw=args.jaw_topic,
                          joint_gap=args.max_joint_gap, right=args.right_image_topic)


def add_threads_argument(p) -> None:
    p.add_argument("--threads", type=int, default=DEFAULT_THREADS, metavar="N",
                   help="threads for BLAS, OpenCV and torch in this process (default: %(default)s; more "
                        "helps only on an otherwise idle machine)")


def threads_from_args(args) -> int:
    if not 1 <= args.threads <= 256:
        raise InputError(f"--threads must be between 1 and 256, got {args.threads}")
    return int(args.threads)
