"""Arm and topic choice: dVRK 1.x and 2.x namings, PSM1-3, overrides, ambiguity."""
import pytest

from graphtrack.errors import InputError
from graphtrack.io.topics import TopicSelection, handeye_arm, resolve_topics

IMG = ("sensor_msgs/msg/Image", 5)
JS = ("sensor_msgs/msg/JointState", 5)


def test_dvrk1_psm1_default():
    r = resolve_topics({"/stereo/left/image": IMG, "/dvrk/PSM1/state_joint_current": JS,
                        "/dvrk/PSM1/state_jaw_current": JS}, TopicSelection(), "b.bag")
    assert (r.arm, r.image, r.joint, r.jaw) == ("PSM1", "/stereo/left/image", "/dvrk/PSM1/state_joint_current",
                                                "/dvrk/PSM1/state_jaw_current")


def test_dvrk2_psm2_detected_without_arm():
    r = resolve_topics({"/stereo/left/image/compressed": IMG, "/PSM2/measured_js": JS,
                        "/PSM2/jaw/measured_js": JS, "/ECM/measured_js": JS}, TopicSelection(), "b.bag")
    assert (r.arm, r.image, r.joint, r.jaw) == ("PSM2", "/stereo/left/image/compressed", "/PSM2/measured_js",
                                                "/PSM2/jaw/measured_js")


def test_several_arms_need_a_choice_and_the_choice_is_honoured():
    topics = {"/stereo/left/image": IMG, "/PSM1/measured_js": JS, "/dvrk/PSM3/state_joint_current": JS}
    with pytest.raises(InputError, match=r"b\.bag: joint topics of several arms \(PSM1, PSM3\).*--arm"):
        resolve_topics(topics, TopicSelection(), "b.bag")
    assert resolve_topics(topics, TopicSelection(arm="PSM3"), "b.bag").joint == "/dvrk/PSM3/state_joint_current"


def test_wrong_arm_names_the_arm_present():
    with pytest.raises(InputError, match=r"no messages on the joint topic of PSM1.*use --arm PSM2"):
        resolve_topics({"/stereo/left/image": IMG, "/PSM2/measured_js": JS}, TopicSelection(arm="PSM1"), "b.bag")


def test_every_other_arm_is_named():
    with pytest.raises(InputError, match=r"joint topics for PSM2, PSM3: use --arm PSM2 or --arm PSM3"):
        resolve_topics({"/stereo/left/image": IMG, "/PSM2/measured_js": JS, "/PSM3/measured_js": JS},
                       TopicSelection(arm="PSM1"), "b.bag")


def test_both_namings_read_dvrk1_and_say_so():
    topics = {"/stereo/left/image": IMG, "/dvrk/PSM1/state_joint_current": JS, "/PSM1/measured_js": JS}
    r = resolve_topics(topics, TopicSelection(), "b.bag")
    assert r.joint == "/dvrk/PSM1/state_joint_current"
    assert r.note.startswith("b.bag: joint topics of PSM1 in both dVRK namings") and "--joint-topic" in r.note
    assert resolve_topics(topics, TopicSelection(joint="/PSM1/measured_js"), "b.bag").note == ""
    assert resolve_topics({"/stereo/left/image": IMG, "/PSM1/measured_js": JS}, TopicSelection(), "b.bag").note == ""


def test_the_right_image_is_never_the_left_one():
    from graphtrack.io.topics import resolve_right

    topics = {"/stereo/left/image": IMG, "/stereo/right/image": IMG}
    assert resolve_right(topics, TopicSelection(), "b.bag", "/stereo/left/image") == ("/stereo/right/image", "")
    # the right camera's topic named as the left image: no right image, not the same one twice
    assert resolve_right(topics, TopicSelection(image="/stereo/right/image"), "b.bag", "/stereo/right/image")[0] is None


def test_overrides_and_their_absence():
    topics = {"/cam/left": IMG, "/my/joints": JS, "/my/jaw": JS}
    r = resolve_topics(topics, TopicSelection(image="/cam/left", joint="/my/joints", jaw="/my/jaw"), "b.bag")
    assert (r.image, r.joint, r.jaw) == ("/cam/left", "/my/joints", "/my/jaw")
    with pytest.raises(InputError, match=r"no left image topic.*--image-topic"):
        resolve_topics(topics, TopicSelection(joint="/my/joints"), "b.bag")
    with pytest.raises(InputError, match=r"joint topic of PSM1 \(/nope\)"):
        resolve_topics(topics, TopicSelection(image="/cam/left", joint="/nope"), "b.bag")


def test_empty_topic_does_not_count():
    with pytest.raises(InputError, match="no messages on the joint topic"):
        resolve_topics({"/stereo/left/image": IMG, "/PSM1/measured_js": ("sensor_msgs/msg/JointState", 0)},
                       TopicSelection(), "b.bag")


@pytest.mark.parametrize("available", [{}, {"/stereo/left/image": ("sensor_msgs/msg/Image", 0),
                                              "/PSM1/measured_js": ("sensor_msgs/msg/JointState", 0)}])
def test_a_bag_without_messages_is_said_to_be_empty(available):
    """Nothing to name: the message says the bag is empty instead of asking for a topic."""
    with pytest.raises(InputError, match=r"^b\.bag: the bag holds no messages") as err:
        resolve_topics(available, TopicSelection(image="/stereo/left/image"), "b.bag")
    assert "--image-topic" not in str(err.value) and ("/PSM1/measured_js" in str(err.value)) == bool(available)


@pytest.mark.parametrize("bad", [dict(arm="PSM4"), dict(arm="psm1"), dict(joint="PSM1/measured_js"),
                                 dict(image="")])
def test_selection_refuses_bad_names(bad):
    with pytest.raises(InputError, match="--"):
        TopicSelection(**bad)


def test_handeye_arm():
    assert handeye_arm({"PSM2_tvec": 0, "PSM2_rvec": 0}, TopicSelection(), "h") == "PSM2"
    assert handeye_arm({"PSM2_tvec": 0}, TopicSelection(arm="PSM3"), "h") == "PSM3"
    assert handeye_arm({}, TopicSelection(), "h") == "PSM1"
    with pytest.raises(InputError, match="several arms"):
        handeye_arm({"PSM1_tvec": 0, "PSM2_tvec": 0}, TopicSelection(), "h")
