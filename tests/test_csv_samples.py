"""What a measurement CSV's cells say of a sample: the NaN spellings loggers write (a missing
sample, a fin held) and the stale repeats of a sensor slower than its logger (missing)."""

import numpy as np
import pytest

from testbed.data import read_csv
from testbed.errors import InputError

SPELLINGS = ("nan", "NaN", "NAN", "-nan", "+nan", "-NaN", "nan(ind)", "-nan(ind)", "NaN(0x7ff8)", "nan(snan)")


def _csv(tmp_path, text, name="e.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("spelling", SPELLINGS)
def test_every_nan_spelling_is_a_missing_state_and_a_held_fin(tmp_path, spelling):
    text = (
        "t,u,r,delta_r,delta_er,delta_el\n"
        "0,1.5,0.01,0.1,0,0\n"
        f"0.1, {spelling} ,0.02,0.2,0,0\n"
        f"0.2,1.7,0.03,{spelling},0,{spelling}\n"
        "0.3,1.8,0.04,0.4,0,0.5\n"
    )
    e = read_csv(_csv(tmp_path, text))
    np.testing.assert_array_equal(e.y[:, 0], [1.5, np.nan, 1.7, 1.8])
    np.testing.assert_array_equal(e.inputs[:, 0], [0.1, 0.2, 0.2, 0.4])
    np.testing.assert_array_equal(e.inputs[:, 2], [0.0, 0.0, 0.0, 0.5])


@pytest.mark.parametrize("cell", ("nan(", "nana", "-nan)", "nan(a b)", "--nan", "n an", "nan()x"))
def test_a_cell_that_only_looks_like_nan_is_refused_by_line_and_column(tmp_path, cell):
    text = f"t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,{cell},0,0,0\n0.2,1,0,0,0\n"
    with pytest.raises(InputError, match=r"line 3, column 'u': .* is not a number"):
        read_csv(_csv(tmp_path, text))


@pytest.mark.parametrize("spelling", ("-nan", "nan(ind)"))
def test_a_nan_time_is_refused(tmp_path, spelling):
    text = f"t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n{spelling},1,0,0,0\n0.2,1,0,0,0\n"
    with pytest.raises(InputError, match=r"line 3, column 't'"):
        read_csv(_csv(tmp_path, text))
