"""robot.json and dVRK config loading: every bad input names the file and field."""
import json
from pathlib import Path

import pytest

from graphtrack.errors import InputError
from graphtrack.robot.description import load_dvrk_config, load_robot_json, save_robot_json
from graphtrack.robot.psm import psm_large_needle_driver


def write(tmp_path, doc):
    p = tmp_path / "robot.json"
    p.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return p


def good():
    return psm_large_needle_driver().to_json()


def _jawless(d):
    """d without its jaws: has_gripper false, nothing on the jaw links (7, 8), the tip on link 6."""
    d.update(has_gripper=False, tool_tip={**d["tool_tip"], "link": 6},
             skeleton_structure=[s for s in d["skeleton_structure"] if max(s["link1"], s["link2"]) <= 6],
             point_features=[p for p in d["point_features"] if p["link"] <= 6])
    return d


def test_roundtrip(tmp_path):
    save_robot_json(tmp_path / "robot.json", psm_large_needle_driver())
    r = load_robot_json(tmp_path / "robot.json")
    assert r.n_dh == 6 and r.has_gripper and r.n_links == 8 and r.tool_tip.link == 7
    assert len(r.point_features) == 4 and r.shaft_features[0].radius == 0.004
    assert all(p.radius == 0.0011 for p in r.point_features)     # the painted discs


def test_marker_radius_is_optional(tmp_path):
    d = good()
    for p in d["point_features"]:
        p.pop("radius")                 # the format doc's point features: name, link, position
    r = load_robot_json(write(tmp_path, d))
    assert all(p.radius == 0.0 for p in r.point_features)
    assert "radius" not in r.to_json()["point_features"][0]


@pytest.mark.parametrize("mutate,needle", [
    (lambda d: d.pop("DH_params"), "DH_params"),
    (lambda d: d["DH_params"][2].pop("alpha"), "joint 3: alpha"),
    (lambda d: d["DH_params"][1].update(type="spherical"), "joint 2: type"),
    (lambda d: d["DH_params"][0].update(A="x"), "joint 1: A"),
    (lambda d: d["point_features"][0].update(link=12), "point_features[0]: link"),
    (lambda d: d["shaft_features"][0].update(position=[0, 0]), "shaft_features[0]: position"),
    (lambda d: d["point_features"][1].update(radius=-0.001), "point_features[1]: radius"),
    (lambda d: d["point_features"][1].update(radius="big"), "point_features[1]: radius"),
    (lambda d: d["point_features"][1].update(radius=0.5), "point_features[1]: radius"),
    (lambda d: d["tool_tip"].pop("link"), "tool_tip: link"),
    (lambda d: d.update(has_gripper="yes"), "has_gripper"),
    (lambda d: d["shaft_features"][0].update(radius=4), "shaft_features[0]: radius: must be in (0, 0.1] m, got 4 "
                                                        "(millimetres? robot.json is in metres)"),
    (lambda d: d["shaft_features"][0].update(direction=[0, 0, 0]), "shaft_features[0]: direction: must be non-zero"),
    (lambda d: d.update(joint_limits=[[-1, 1]] * 8), "joint_limits: expected 6 (the DH joints) or 7 (and the jaw) "
                                                     "pairs [qmin, qmax], got 8 pairs"),
    (lambda d: _jawless(d).update(joint_limits=[[-1, 1]] * 7),
     "joint_limits: expected 6 pairs [qmin, qmax], got 7 pairs (a jaw pair, but has_gripper is false)"),
    (lambda d: d.update(joint_limits=[[-1, 1]] * 6 + [[0, "x"]]),
     'joint_limits: pair 6 is not [qmin, qmax] of two numbers: [0, "x"]'),
])
def test_bad_robot_json(tmp_path, mutate, needle):
    d = good()
    mutate(d)
    with pytest.raises(InputError) as e:
        load_robot_json(write(tmp_path, d))
    assert "robot.json" in str(e.value) and needle in str(e.value)


def test_not_json_and_missing(tmp_path):
    with pytest.raises(InputError, match="not valid JSON"):
        load_robot_json(write(tmp_path, "{nope"))
    with pytest.raises(InputError, match="file not found"):
        load_robot_json(tmp_path / "missing.json")


def test_dvrk_files_with_comments_and_both_layouts(tmp_path):
    arm = tmp_path / "arm.json"
    arm.write_text('/* arm */ {"DH": {"convention": "modified", "joints": [ // three\n'
                   + ",".join('{"alpha": 0.1, "A": 0, "theta": 0, "D": 0, "type": "revolute", "offset": 0} // j\n'
                              for _ in range(3)) + "]}}")
    tool = tmp_path / "tool.json"
    tool.write_text('{"DH": {"links": [' + ",".join(
        '{"convention": "modified", "alpha": 0, "A": 0, "theta": 0, "D": 0.1, "type": "revolute"}'
        for _ in range(3)) + ']}, "jaw": {}}')
    r = load_dvrk_config(arm, tool)
    assert r.n_dh == 6 and r.has_gripper
    tool.write_text('{"DH": {"convention": "standard", "links": []}}')
    with pytest.raises(InputError, match="tool.json"):
        load_dvrk_config(arm, tool)


def _dvrk_links(path) -> list[dict]:
    """The joints of a dVRK configuration file, read here without graphtrack's parser."""
    import re

    text = re.sub(r"/\*.*?\*/", "", Path(path).read_text(), flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    dh = json.loads(text)["DH"]
    return dh.get("joints") or dh["links"]


def test_robot_command_writes_the_dvrk_files_kinematics_and_the_given_features(tmp_path, capsys):
    from graphtrack.cli import main

    dvrk = Path(__file__).resolve().parents[1] / "graphtrack" / "data" / "dvrk"
    arm, tool = dvrk / "psm.json", dvrk / "LARGE_NEEDLE_DRIVER_400006.json"
    features = json.loads(json.dumps(good()))
    features["tool_tip"] = {"link": 7, "position": [0.0, 0.0123, 0.0]}
    (tmp_path / "features.json").write_text(json.dumps(features))
    out = tmp_path / "seq" / "robot.json"
    assert main(["robot", str(arm), str(tool), "--out", str(out), "--features-from",
                 str(tmp_path / "features.json")]) == 0
    written = json.loads(out.read_text())
    expected = _dvrk_links(arm) + _dvrk_links(tool)
    assert len(written["DH_params"]) == len(expected) == 6 and written["has_gripper"] is True
    for got, want in zip(written["DH_params"], expected):
        assert got["type"] == want["type"]
        for key in ("alpha", "A", "theta", "D", "offset"):
            assert got[key] == pytest.approx(want[key]), (key, got, want)
    assert written["tool_tip"] == features["tool_tip"]
    assert written["shaft_features"] == features["shaft_features"]
    assert load_robot_json(out).n_dh == 6
    capsys.readouterr()
    assert main(["robot", str(arm), str(tool), "--out", str(out)]) == 2          # never overwrites silently
    assert "--overwrite" in capsys.readouterr().err

