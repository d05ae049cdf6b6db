"""One value's checks (``soil_msgs_py.values``): the words every parameter check names a bad value with."""
import math

import pytest

from soil_msgs_py.values import finite_number, number_in, short_repr


def test_a_number_in_its_range_is_taken_as_a_float_and_each_end_is_closed_or_open_as_said():
    assert number_in("wait_s", 0, 0.0, 60.0) == 0.0 and isinstance(number_in("wait_s", 3, 0.0, 60.0), float)
    assert number_in("wait_s", 60.0, 0.0, 60.0) == 60.0
    with pytest.raises(ValueError, match=r"^wait_s=0\.0 must be a number of seconds in \(0, 60\]$"):
        number_in("wait_s", 0.0, 0.0, 60.0, lo_open=True, what="a number of seconds")
    with pytest.raises(ValueError, match=r"^rate=10 must be a number in \[0, 10\) m/s \(0: off\)$"):
        number_in("rate", 10, 0.0, 10.0, hi_open=True, unit=" m/s", note=" (0: off)")


@pytest.mark.parametrize("bad", [True, False, "1", None, math.nan, math.inf, -math.inf, 10**400, [1.0], -0.5, 61])
def test_what_is_no_finite_number_in_range_is_refused_naming_it_shortly(bad):
    with pytest.raises(ValueError) as err:
        number_in("planner_wait_s", bad, 0.0, 60.0)
    said = str(err.value)
    assert said.startswith(f"planner_wait_s={short_repr(bad)} must be a number in [0, 60]") and len(said) < 120, said
    assert not finite_number(bad) or not 0.0 <= bad <= 60.0
