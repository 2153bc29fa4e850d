"""errors.number_list: the one reader of a list-of-numbers key in the configuration files;
errors.is_whole: what a count may be."""
import numpy as np
import pytest

from graphtrack.errors import InputError, is_whole, number_list


def test_plain_list_and_data_mapping_read_alike():
    doc = {"K": [1, 2.5, 3], "M": {"rows": 1, "cols": 3, "dt": "d", "data": [1, 2.5, 3]}}
    np.testing.assert_array_equal(number_list(doc, "K", "c.yaml", (3,)), [1.0, 2.5, 3.0])
    np.testing.assert_array_equal(number_list(doc, "M", "c.yaml", (3,)), [1.0, 2.5, 3.0])
    assert number_list({"D": []}, "D", "c.yaml").size == 0   # no sizes: any length


@pytest.mark.parametrize("doc, match", [
    ({}, r"c\.yaml: missing key 'K' \(hint\)"),
    ({"K": {"rows": 3}}, r"c\.yaml: key 'K' has no 'data' field"),
    ({"K": [1, "2", 3]}, r"c\.yaml: key 'K' must be a flat list of numbers"),
    ({"K": [[1, 2, 3]]}, r"c\.yaml: key 'K' must be a flat list of numbers"),
    ({"K": [1, True, 3]}, r"c\.yaml: key 'K' must be a flat list of numbers"),
    ({"K": [1, float("nan"), 3]}, r"c\.yaml: key 'K' holds NaN"),
    ({"K": [1, 10**400, 3]}, r"c\.yaml: key 'K' holds NaN, infinite or out-of-range"),
    ({"K": [1, 2]}, r"c\.yaml: key 'K' has 2 values, expected 3 or 9"),
])
def test_bad_values_name_the_file_and_key(doc, match):
    with pytest.raises(InputError, match=match):
        number_list(doc, "K", "c.yaml", (3, 9), missing=" (hint)")


def test_a_key_given_twice_is_refused_not_resolved_silently(tmp_path):
    """YAML and JSON parsers let the last of two equal keys win; a configuration file with
    one key twice is refused, naming the key (and for YAML its lines)."""
    from graphtrack.errors import read_json, read_yaml

    y = tmp_path / "handeye.yaml"
    y.write_text("PSM1_tvec: [1, 2, 3]\nPSM1_rvec: [0, 0, 0]\nPSM1_tvec: [4, 5, 6]\n")
    with pytest.raises(InputError, match=r"handeye.yaml: key 'PSM1_tvec' appears twice \(lines 1 and 3\)"):
        read_yaml(y)
    y.write_text("a: {x: 1, y: 2}\nb: {x: 3}\n")                  # equal keys in different mappings
    assert read_yaml(y) == {"a": {"x": 1, "y": 2}, "b": {"x": 3}}
    j = tmp_path / "robot.json"
    j.write_text('{"DH_params": [], // a dVRK comment\n "tool_tip": {"link": 1}, "DH_params": [1]}')
    with pytest.raises(InputError, match=r"robot.json: key 'DH_params' appears twice"):
        read_json(j)
    j.write_text('{"a": {"k": 1}, /* "a": 2 */ "b": {"k": "//not a comment"}}')
    assert read_json(j) == {"a": {"k": 1}, "b": {"k": "//not a comment"}}
    j.write_text('{"a": 1,}')
    with pytest.raises(InputError, match=r"robot.json: not valid JSON \(line 1"):
        read_json(j)


@pytest.mark.parametrize("v, whole", [(3, True), (np.int64(3), True), (np.uint8(0), True), (-1, True),
                                      (3.0, False), (2.5, False), (True, False), (np.bool_(True), False),
                                      ("3", False), (None, False)])
def test_is_whole_takes_integers_of_python_and_numpy_never_bools(v, whole):
    assert is_whole(v) is whole


def test_yaml_numbers_with_an_exponent_are_numbers(tmp_path):
    """YAML 1.1 reads 1e-3 or 1.0e6 as text (no point, or no sign in the exponent); a
    calibration written so is read as numbers, as Python's float() reads each."""
    from graphtrack.errors import read_yaml

    y = tmp_path / "camera_calibration.yaml"
    values = ["1e-3", "5e2", "1.0e6", "-2E+3", "1.5e-7"]
    y.write_text(f"D1: [{', '.join(values)}]\nK: '1e3'\nname: 1e3x\n")
    doc = read_yaml(y)
    assert doc["D1"] == [float(v) for v in values] and all(isinstance(v, float) for v in doc["D1"])
    assert doc["K"] == "1e3" and doc["name"] == "1e3x"   # quoted, or not a number: text as before
