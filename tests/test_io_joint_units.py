"""Joint readings in radians and metres (graphtrack/io/joint_units.py)."""
import math

import numpy as np
import pytest

from graphtrack.errors import FrameError, InputError
from graphtrack.io.joint_units import (MAX_JOINT, MAX_PRISMATIC_M, MAX_REVOLUTE_RAD, check_table, joint_bounds,
                                       out_of_range)
from graphtrack.robot.description import DHJoint, RobotDescription

PSM = RobotDescription([DHJoint(t, 0.0, 0.0, 0.0, 0.0) for t in ("revolute", "revolute", "prismatic",
                                                                  "revolute", "revolute", "revolute")], True)


def test_bounds_follow_the_joint_types():
    np.testing.assert_array_equal(joint_bounds(PSM, 6), [2 * math.pi] * 2 + [1.0] + [2 * math.pi] * 3)
    assert joint_bounds(PSM, 7) is None and joint_bounds(None, 6) is None and joint_bounds(PSM, None) is None


def test_a_reading_in_degrees_or_millimetres_is_named():
    b = joint_bounds(PSM, 6)
    q = np.array([0.1, -0.3, 0.12, -4.5, 1.2, -1.2])           # a PSM's widest roll, in radians: fine
    assert out_of_range(q, 0.7, b, True) is None
    why = out_of_range(np.r_[q[:3], math.degrees(-0.3), q[4:]], 0.7, b, True)
    assert why.startswith("q4 = -17.1887 is beyond a full turn") and "(degrees?)" in why
    why = out_of_range(np.r_[q[:2], 120.0, q[3:]], 0.7, b, True)        # insertion in mm
    assert why.startswith("q3 = 120 is beyond |q| <= 1 m") and "(millimetres?)" in why
    assert out_of_range(q, 40.0, b, True).startswith("jaw = 40 is beyond a full turn")
    assert out_of_range(q, 40.0, b, False) is None               # no jaw topic: the value is not read
    # the robot's types unknown: only the loose bound
    assert out_of_range(np.r_[q[:2], 60.0, q[3:]], 0.7, None, True) is None
    assert "100" in out_of_range(np.r_[q[:2], 120.5 * 1000, q[3:]], 0.7, None, True)
    assert MAX_REVOLUTE_RAD == 2 * math.pi and MAX_PRISMATIC_M == 1.0 and MAX_JOINT == 100.0


def test_a_table_mostly_out_of_range_is_refused_a_few_rows_are_not(tmp_path):
    b = joint_bounds(PSM, 6)
    q = np.tile([0.1, -0.3, 0.12, -1.0, 1.2, -1.2], (10, 1))
    jaw = np.full(10, 0.5)
    check_table(q, jaw, b, True, tmp_path / "joints.csv")         # fine
    q[[2, 7], 3] = 400.0                                           # two damaged rows: per-frame skips
    check_table(q, jaw, b, True, tmp_path / "joints.csv")
    q[:, 0] = np.degrees(q[:, 0]) * 100                            # every row: refused
    with pytest.raises(InputError, match=r"joints\.csv: 10 of 10 rows .* \(first: frame 0, q1 = 572\.958"):
        check_table(q, jaw, b, True, tmp_path / "joints.csv")


def test_one_row_in_degrees_is_a_counted_skip(tmp_path):
    from graphtrack.io.recording import open_recording
    from graphtrack.sim.simulate import simulate

    rec = tmp_path / "rec"
    simulate(rec, frames=6, size=(90, 160), form="folder", progress=False)
    rows = (rec / "joints.csv").read_text().splitlines()
    cells = rows[3].split(",")
    cells[5] = repr(math.degrees(float(cells[5])) + 400.0)        # frame 2's q4, far beyond a turn
    rows[3] = ",".join(cells)
    (rec / "joints.csv").write_text("\n".join(rows) + "\n")
    out = list(open_recording(rec).frames())
    bad = [f for f in out if isinstance(f, FrameError)]
    assert [(f.frame, f.reason) for f in bad] == [(2, "joint_range")] and "q4 = " in str(bad[0])


def test_stamps_a_second_or_more_apart_are_warned_about(tmp_path):
    """Milliseconds of a 100 frames/s camera read as seconds are 10 apart: under the
    refusal's 10 s, so they are warned about; seconds at 30 frames/s are not."""
    import csv

    from graphtrack.io.recording import open_recording
    from graphtrack.sim.simulate import simulate

    seq = simulate(tmp_path / "rec", "tissue", frames=4, seed=1, size=(270, 480), progress=False, form="folder")
    assert not any("apart" in w for w in open_recording(seq).warnings)
    rows = list(csv.reader((seq / "joints.csv").open()))
    for r in rows[1:]:
        r[1] = repr(int(r[0]) * 10.0)          # 10 ms between frames, written as 10
    with (seq / "joints.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    warned = [w for w in open_recording(seq).warnings if "apart" in w]
    assert len(warned) == 1 and "joints.csv: the stamps are 10 s apart (median)" in warned[0]
