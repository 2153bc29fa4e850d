"""A lab's own recording, as the docs tell a user to assemble it: a dVRK 2.x PSM2 bag.

The bag carries dVRK 2.x topics (/PSM2/measured_js, /PSM2/jaw/measured_js) and
JPEG CompressedImages; handeye.yaml has PSM2 keys; robot.json is written by
``graphtrack robot`` from the dVRK's own arm and tool files. ``graphtrack track``
is run without --arm or topic options and must find PSM2 itself.
"""
import json
import shutil
from pathlib import Path

import pytest

from graphtrack.cli import main
from graphtrack.errors import FrameError
from graphtrack.io.bag_write import write_bag
from graphtrack.io.handeye import load_handeye, save_handeye
from graphtrack.io.recording import open_recording
from graphtrack.sim.simulate import simulate

DVRK = Path(__file__).resolve().parents[1] / "graphtrack" / "data" / "dvrk"


@pytest.fixture(scope="module")
def psm2_dvrk2(tmp_path_factory):
    root = tmp_path_factory.mktemp("dvrk2")
    sim = simulate(root / "sim", scene="tissue", frames=30, seed=21, size=(540, 960), form="folder",
                   progress=False)
    seq = root / "seq"
    seq.mkdir()
    frames = [f for f in open_recording(sim).frames() if not isinstance(f, FrameError)]
    write_bag(seq / "psm2.bag", frames, compressed=True, image_format="jpeg", arm="PSM2", dvrk_version=2)
    save_handeye(seq / "handeye.yaml", load_handeye(sim / "handeye.yaml"), arm="PSM2")
    for name in ("camera_calibration.yaml", "labels.csv"):
        shutil.copy(sim / name, seq / name)
    assert main(["robot", str(DVRK / "psm.json"), str(DVRK / "LARGE_NEEDLE_DRIVER_400006.json"),
                 "--out", str(seq / "robot.json")]) == 0
    return seq


def test_bag_holds_only_dvrk2_psm2_names(psm2_dvrk2):
    rec = open_recording(psm2_dvrk2)
    src = rec.source
    assert (src.arm, src.joint_topic, src.jaw_topic) == ("PSM2", "/PSM2/measured_js", "/PSM2/jaw/measured_js")
    assert src.image_topic == "/stereo/left/image/compressed" and rec.has_jaw and len(rec) == 30
    assert "PSM1_tvec" not in (psm2_dvrk2 / "handeye.yaml").read_text()


@pytest.mark.slow
def test_track_psm2_dvrk2_bag_with_the_documented_command(psm2_dvrk2, tmp_path):
    runs = {}
    for est in ("kinematics", "smoother"):
        out = tmp_path / est
        assert main(["track", str(psm2_dvrk2), "--out", str(out), "--estimator", est, "--quiet"]) == 0
        runs[est] = json.loads((out / "metrics.json").read_text())
        rows = (out / "trajectory.csv").read_text().strip().splitlines()
        assert len(rows) == 1 + 30
    assert runs["smoother"]["frames_tracked"] == 30
    # the labels are the true tip + 1.2 px noise: tracking must beat the uncorrected kinematics
    assert runs["smoother"]["tip_error_px"]["mean"] < 0.5 * runs["kinematics"]["tip_error_px"]["mean"]


def test_wrong_arm_is_one_clear_error(psm2_dvrk2, tmp_path, capsys):
    assert main(["track", str(psm2_dvrk2), "--out", str(tmp_path / "o"), "--arm", "PSM1",
                 "--estimator", "kinematics", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "PSM2" in err[0] and "--arm" in err[0], err


def test_a_missing_jaw_topic_is_named_as_this_arm_and_version_call_it(psm2_dvrk2, tmp_path, capsys):
    seq = tmp_path / "seq"
    shutil.copytree(psm2_dvrk2, seq)
    frames = [f for f in open_recording(psm2_dvrk2).frames() if not isinstance(f, FrameError)][:5]
    for f in frames:
        f.jaw = float("nan")   # write_bag: no jaw message
    (seq / "psm2.bag").unlink()
    write_bag(seq / "psm2.bag", frames, compressed=True, image_format="jpeg", arm="PSM2", dvrk_version=2)
    assert main(["track", str(seq), "--out", str(tmp_path / "o"), "--estimator", "kinematics", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no messages on /PSM2/jaw/measured_js" in err[0] and "PSM1" not in err[0], err


def test_joint_messages_are_read_by_their_names(psm2_dvrk2, tmp_path):
    """A JointState whose name[] lists the PSM's joints in another order (a republished
    /joint_states) is read in DH order: the same joint readings as the unnamed bag's."""
    from graphtrack.io.joint_names import DVRK_PSM_JOINTS

    frames = [f for f in open_recording(psm2_dvrk2).frames() if not isinstance(f, FrameError)][:5]
    seq = tmp_path / "named"
    shutil.copytree(psm2_dvrk2, seq, ignore=shutil.ignore_patterns("*.bag"))
    names = [DVRK_PSM_JOINTS[i] for i in (3, 0, 5, 1, 2, 4)]
    write_bag(seq / "psm2.bag", frames, compressed=True, image_format="jpeg", arm="PSM2", dvrk_version=2,
              joint_names=names)
    got = [f for f in open_recording(seq).frames() if not isinstance(f, FrameError)]
    assert len(got) == 5
    for a, b in zip(frames, got):
        assert list(b.joints) == list(a.joints) and b.jaw == a.jaw


def test_joint_messages_with_another_arms_names_are_refused(psm2_dvrk2, tmp_path, monkeypatch, capsys):
    """Names in DH order read in place; half of the PSM's names (an ECM's topic) exit 2 naming the topic."""
    from graphtrack.io import bag_write
    from graphtrack.io.joint_names import DVRK_PSM_JOINTS

    frames = [f for f in open_recording(psm2_dvrk2).frames() if not isinstance(f, FrameError)][:3]
    seqs = {}
    for kind in ("in-order", "three-names"):
        seqs[kind] = seq = tmp_path / kind
        shutil.copytree(psm2_dvrk2, seq, ignore=shutil.ignore_patterns("*.bag"))
        if kind == "three-names":   # the arm joints' names only: an ECM-like message
            real = bag_write._joint_state
            monkeypatch.setattr(bag_write, "_joint_state",
                                lambda T, hdr, position, names=(): real(T, hdr, position, list(names)[:3]))
        write_bag(seq / "psm2.bag", frames, compressed=True, image_format="jpeg", arm="PSM2", dvrk_version=2,
                  joint_names=list(DVRK_PSM_JOINTS))
    got = [list(f.joints) for f in open_recording(seqs["in-order"]).frames()]
    assert got == [list(f.joints) for f in frames]
    assert main(["track", str(seqs["three-names"]), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "/PSM2/measured_js: a joint message holds 3 of the dVRK PSM's 6" in capsys.readouterr().err
