"""Which bag topics and hand-eye keys belong to the tracked arm (format doc, "The bag").

A dVRK recording names the tracked arm twice: in its joint topics and in the
keys of handeye.yaml (``PSM1_tvec``). Two topic namings are in use:

=========  ==================================  ==========================
dVRK       joints (DH joints, ``position``)      jaw (one value)
=========  ==================================  ==========================
1.x        ``/dvrk/PSM1/state_joint_current``  ``/dvrk/PSM1/state_jaw_current``
2.x        ``/PSM1/measured_js``               ``/PSM1/jaw/measured_js``
=========  ==================================  ==========================

:class:`TopicSelection` says what the user asked for (all optional);
:func:`resolve_topics` turns it and the bag's topic list into the topics read.
With no arm given, the arm is the one whose joint topic the bag carries; a bag
with several arms' joint topics needs ``--arm``.
"""
from __future__ import annotations

from dataclasses import dataclass

from graphtrack.errors import InputError

ARMS = ("PSM1", "PSM2", "PSM3")
DEFAULT_ARM = "PSM1"
#: s: the most --max-joint-gap allows (a reading farther than that belongs to another moment)
MAX_JOINT_GAP_S = 10.0
IMAGE_TOPICS = ("/stereo/left/image", "/stereo/left/image/compressed")
RIGHT_IMAGE_TOPICS = ("/stereo/right/image", "/stereo/right/image/compressed")


@dataclass(frozen=True)
class TopicSelection:
    """The user's choice of arm and topics; None everywhere means "detect it".

    arm: PSM1 | PSM2 | PSM3 (the joint topics and the handeye.yaml keys);
    image / joint / jaw / right: explicit topic names (right: the stereo right image),
    overriding the conventions;
    joint_gap: s, how far an image may lie from its nearest joint (and jaw) reading,
    overriding the bag's rule (0.2 s, or 3 median periods of a slower topic).
    """

    arm: str | None = None
    image: str | None = None
    joint: str | None = None
    jaw: str | None = None
    joint_gap: float | None = None
    right: str | None = None

    def __post_init__(self):
        if self.arm is not None and self.arm not in ARMS:
            raise InputError(f"--arm: unknown arm {self.arm!r} (choose from {', '.join(ARMS)})")
        for name, flag in (("image", "image"), ("joint", "joint"), ("jaw", "jaw"), ("right", "right-image")):
            t = getattr(self, name)
            if t is not None and not (isinstance(t, str) and t.startswith("/") and len(t) > 1):
                raise InputError(f"--{flag}-topic: a topic name starts with '/', got {t!r}")
        g = self.joint_gap
        if g is not None and not (isinstance(g, (int, float)) and not isinstance(g, bool) and 0 < g <= MAX_JOINT_GAP_S):
            raise InputError(f"--max-joint-gap: seconds in (0, {MAX_JOINT_GAP_S:g}], got {g!r}")


@dataclass(frozen=True)
class ResolvedTopics:
    """The topics read from one bag: arm, left image, joints, jaw (may be absent from the bag);
    note: a line for the user about the choice ("" when there is nothing to say)."""

    arm: str
    image: str
    joint: str
    jaw: str
    note: str = ""


def joint_topics(arm: str) -> tuple[str, str]:
    """The joint topic of ``arm`` in dVRK 1.x and 2.x naming."""
    return f"/dvrk/{arm}/state_joint_current", f"/{arm}/measured_js"


def jaw_topics(arm: str) -> tuple[str, str]:
    """The jaw topic of ``arm`` in dVRK 1.x and 2.x naming (same order as joint_topics)."""
    return f"/dvrk/{arm}/state_jaw_current", f"/{arm}/jaw/measured_js"


def arms_in(topics) -> list[str]:
    """The arms whose joint topic (either naming) is among ``topics``."""
    return [a for a in ARMS if any(t in topics for t in joint_topics(a))]


def resolve_topics(available: dict[str, tuple[str, int]], sel: TopicSelection, where: str) -> ResolvedTopics:
    """Choose the arm and the image, joint and jaw topics of a bag.

    available: topic -> (message type, message count). Raises InputError naming
    ``where`` (the bag) and what to pass when the choice is missing or ambiguous.
    """
    present = {t for t, (_, n) in available.items() if n > 0}
    if not present:   # no topic to name: say so instead of asking for one
        listed = f" (its topics, all without messages: {', '.join(sorted(available))})" if available else ""
        raise InputError(f"{where}: the bag holds no messages{listed}; a recording needs the left images and "
                         "the arm's joint states (docs/sequence-format.md)")
    arm = sel.arm
    if arm is None:
        found = arms_in(present)
        if len(found) > 1 and sel.joint is None:
            raise InputError(f"{where}: joint topics of several arms ({', '.join(found)}); "
                             "choose one with --arm")
        arm = found[0] if found else DEFAULT_ARM
    # the raw topic, else the compressed one: the first that holds messages (a recorder may
    # advertise both and publish one)
    image = sel.image or next((t for t in IMAGE_TOPICS if t in present), None) or next(
        (t for t in IMAGE_TOPICS if t in available), None)
    if image is None or image not in available:
        raise InputError(f"{where}: no left image topic ({sel.image or ' or '.join(IMAGE_TOPICS)}); "
                         f"topics: {', '.join(sorted(available)) or 'none'}; name it with --image-topic")
    if image not in present:
        raise InputError(f"{where}: the left image topic {image} holds no messages; topics with messages: "
                         f"{', '.join(sorted(present)) or 'none'}; name another with --image-topic")
    naming = 1 if joint_topics(arm)[1] in present and joint_topics(arm)[0] not in present else 0
    joint = sel.joint or joint_topics(arm)[naming]
    if joint not in present:
        others = [a for a in arms_in(present) if a != arm]
        hint = (f"; the bag has joint topics for {', '.join(others)}: use --arm {' or --arm '.join(others)}"
                if others else "; name it with --joint-topic")
        asked = sel.joint or " or ".join(joint_topics(arm))
        raise InputError(f"{where}: no messages on the joint topic of {arm} ({asked}){hint}")
    jaw = sel.jaw or jaw_topics(arm)[naming]
    note = ""
    if sel.joint is None and all(t in present for t in joint_topics(arm)):
        note = (f"{where}: joint topics of {arm} in both dVRK namings ({' and '.join(joint_topics(arm))}); "
                f"reading {joint} and {jaw}: name others with --joint-topic / --jaw-topic")
    return ResolvedTopics(arm, image, joint, jaw, note)


def resolve_right(available: dict[str, tuple[str, int]], sel: TopicSelection, where: str,
                  left: str) -> tuple[str | None, str]:
    """The stereo right image topic of a bag, or None (mono), and a note ("" if none).

    ``--right-image-topic`` if given (it must carry messages and not be ``left``, the
    left image's topic); else, when ``--image-topic`` names the left image, the same name
    with its last "left" made "right", if the bag carries it; else the first of
    RIGHT_IMAGE_TOPICS the bag carries, unless it is the left image's."""
    present = {t for t, (_, n) in available.items() if n > 0}
    if sel.right is not None:
        if sel.right not in present:
            raise InputError(f"{where}: no messages on --right-image-topic {sel.right}")
        if sel.right == left:
            raise InputError(f"{where}: --right-image-topic {sel.right} is the left image's topic too")
        return sel.right, ""
    if sel.image is not None and "left" in sel.image:
        i = sel.image.rindex("left")
        twin = sel.image[:i] + "right" + sel.image[i + 4:]
        if twin in present:
            return twin, (f"{where}: right images from {twin}, the twin of --image-topic {sel.image} "
                          "(--right-image-topic names another, --mono leaves them out)")
    return next((t for t in RIGHT_IMAGE_TOPICS if t in present and t != left), None), ""


def handeye_arm(keys, sel: TopicSelection, where: str) -> str:
    """The arm whose ``<ARM>_tvec`` / ``<ARM>_rvec`` keys are read from handeye.yaml.

    The arm asked for; else the prefix of the file's only ``*_tvec`` key; else PSM1.
    """
    if sel.arm is not None:
        return sel.arm
    found = sorted(k[: -len("_tvec")] for k in keys if isinstance(k, str) and k.endswith("_tvec"))
    if len(found) > 1:
        raise InputError(f"{where}: hand-eye keys for several arms ({', '.join(found)}); choose one with --arm")
    if found and found[0].upper() not in ARMS:
        raise InputError(f"{where}: keys '{found[0]}_tvec' / '{found[0]}_rvec' name no arm graphtrack tracks "
                         f"({', '.join(ARMS)}): the file holds the camera-from-base transform of the tracked PSM, "
                         f"its keys prefixed with that arm (e.g. PSM1_tvec); an ECM's or another device's "
                         "registration is another transform")
    return found[0] if found else DEFAULT_ARM
