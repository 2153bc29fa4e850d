"""Joint messages read by name: a ``sensor_msgs/JointState`` lists its values in
``name[]``'s order, which need not be the DH order robot.json's chain expects (a
republished or merged ``/joint_states``).

The dVRK names its PSM joints, in DH order, ``DVRK_PSM_JOINTS`` (dVRK 1.x
``state_joint_current`` and 2.x ``measured_js`` alike). A message whose names hold
each of them once is read in that order, any other values (e.g. a ``jaw``)
after them in their own order; a message without names, or with none of them
(another robot's), in the order given. Some of them but not all, or one twice (two
arms on one topic), cannot be read either way: InputError naming the topic.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from graphtrack.errors import InputError

#: the dVRK PSM's joint names in DH order (outer yaw, pitch, insertion; the tool's roll,
#: wrist pitch, wrist yaw)
DVRK_PSM_JOINTS = ("outer_yaw", "outer_pitch", "outer_insertion", "outer_roll", "outer_wrist_pitch",
                   "outer_wrist_yaw")


def missing_and_repeated(names: Sequence[str]) -> tuple[list[str], list[str]]:
    """The dVRK PSM joint names absent from ``names``, and those in it more than once (DH order)."""
    names = [str(n) for n in names]
    return ([n for n in DVRK_PSM_JOINTS if n not in names],
            [n for n in DVRK_PSM_JOINTS if names.count(n) > 1])


def name_order(names: Sequence[str], where: str) -> np.ndarray | None:
    """Indices that put a message's values in DH order (module doc); None: as given.

    ``where`` names the topic for the error of a partial or repeated set of the dVRK names."""
    names = [str(n) for n in names]
    if not any(n in names for n in DVRK_PSM_JOINTS):
        return None
    missing, repeated = missing_and_repeated(names)
    if repeated or missing:
        why = (f"names {', '.join(repeated)} more than once (two arms on one topic?)" if repeated else
               f"holds {len(DVRK_PSM_JOINTS) - len(missing)} of the dVRK PSM's {len(DVRK_PSM_JOINTS)} joint "
               f"names (missing {', '.join(missing)}; another arm's topic?)")
        raise InputError(f"{where}: a joint message {why}: its values cannot be put in the PSM's DH order "
                         f"({', '.join(DVRK_PSM_JOINTS)}); name the PSM's joint topic with --joint-topic")
    first = [names.index(n) for n in DVRK_PSM_JOINTS]
    order = np.array(first + [i for i in range(len(names)) if i not in first])
    return None if np.array_equal(order, np.arange(len(names))) else order


def in_dh_order(values: list[np.ndarray], names: list[tuple[str, ...]], where: str) -> list[np.ndarray]:
    """Each message's values (``values[i]``, named ``names[i]``) in DH order (:func:`name_order`);
    values without a name each, or with another count of names than values, stay as given."""
    orders: dict[tuple[str, ...], np.ndarray | None] = {}
    out = []
    for v, n in zip(values, names):
        if n not in orders:
            orders[n] = name_order(n, where) if n else None
        order = orders[n]
        out.append(v[order] if order is not None and len(n) == len(v) else v)
    return out
