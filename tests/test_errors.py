"""errors.number_list: the one reader of a list-of-numbers key in the configuration files."""
import numpy as np
import pytest

from graphtrack.errors import InputError, number_list


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
