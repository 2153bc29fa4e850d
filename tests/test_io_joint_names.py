"""Joint messages put in DH order by their names (graphtrack.io.joint_names), against
hand-written permutations."""
import numpy as np
import pytest

from graphtrack.errors import InputError
from graphtrack.io.joint_names import DVRK_PSM_JOINTS, in_dh_order, name_order

Y, P, I, R, WP, WY = DVRK_PSM_JOINTS


def test_dh_order_is_read_as_given():
    assert name_order(list(DVRK_PSM_JOINTS), "T") is None
    assert name_order([], "T") is None
    assert name_order(["shoulder", "elbow"], "T") is None       # another robot's names: as given


def test_a_permutation_and_extra_values():
    assert name_order([R, Y, WY, P, I, WP], "T").tolist() == [1, 3, 4, 0, 5, 2]
    # a jaw among them goes after the six, where the 7th-value check finds it
    assert name_order(["jaw", Y, P, I, R, WP, WY], "T").tolist() == [1, 2, 3, 4, 5, 6, 0]
    v = np.array([4.0, 1.0, 6.0, 2.0, 3.0, 5.0])
    out = in_dh_order([v, v[:5]], [(R, Y, WY, P, I, WP)] * 2, "T")
    assert out[0].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert out[1] is not None and out[1].tolist() == v[:5].tolist()   # 6 names, 5 values: as given
    assert in_dh_order([v], [()], "T")[0] is v


@pytest.mark.parametrize("names, why", [
    ([Y, P, "insertion", R], "holds 3 of the dVRK PSM's 6"),          # an ECM
    ([Y, P, I, R, WP, WY, Y], "names outer_yaw more than once"),       # two arms on one topic
])
def test_partial_or_repeated_names_are_refused(names, why):
    with pytest.raises(InputError, match=why) as e:
        name_order(names, "psm.bag: /PSM1/measured_js")
    assert str(e.value).startswith("psm.bag: /PSM1/measured_js: ") and "--joint-topic" in str(e.value)
