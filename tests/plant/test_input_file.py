"""u(t) files for the throttle plant (issue 18 item 1): reading, checks, playback at 1 kHz."""

from __future__ import annotations

import numpy as np
import pytest

from vecu.errors import BadFileError
from vecu.plant.input_file import FileInput, load_input_file


def test_a_file_is_read_in_any_column_order_and_played_interpolated_then_held(tmp_path):
    path = tmp_path / "u.csv"
    path.write_text("# bench run 3\nextra,U_V,T_S\nx,1.0,0.0\n\ny,3.0,0.002\nz,0.5,0.004\n")
    series = load_input_file(path)
    assert series.t_s.tolist() == [0.0, 0.002, 0.004] and series.u_v.tolist() == [1.0, 3.0, 0.5]
    gen = FileInput(series)
    got = [gen.next() for _ in range(2500)]  # past one interpolation chunk
    assert got[:6] == pytest.approx([1.0, 2.0, 3.0, 1.75, 0.5, 0.5])
    assert set(got[4:]) == {0.5}


def test_playback_matches_the_rows_over_many_chunks(tmp_path):
    t = np.arange(0.0, 3.0, 0.0005)
    u = 5.0 + 4.0 * np.sin(2 * np.pi * 1.3 * t)
    path = tmp_path / "u.csv"
    path.write_text("t_s,u_V\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(t, u, strict=True)))
    gen = FileInput(load_input_file(path))
    got = np.array([gen.next() for _ in range(2999)])
    np.testing.assert_allclose(got, u[::2][:2999], atol=1e-12)
    # take(n) (the throttle part's blocks) gives what as many next() calls give
    a, b = FileInput(load_input_file(path)), FileInput(load_input_file(path))
    taken = a.take(7) + a.take(1500) + [a.next()] + a.take(1491)
    assert taken == [b.next() for _ in range(2999)] and taken == got.tolist()


@pytest.mark.parametrize(("text", "problem"), [
    ("", "empty"),
    ("# only a comment\n\n", "empty"),
    ("t_s,u_V\n", "no data rows"),
    ("time,u_V\n0,1\n", "line 1: no t_s column"),
    ("t_s,volts\n0,1\n", "line 1: no u_V column"),
    ("t_s,u_V\n0,1\n0.001,high\n", "line 3: u_V 'high' is not a number"),
    ("t_s,u_V\n0,1\nabc,2\n", "line 3: t_s 'abc' is not a number"),
    ("t_s,u_V\n0,1\n0.001,nan\n", "line 3: u_V 'nan' is not finite"),
    ("t_s,u_V\n0,1\n0.002,2\n0.001,2\n", "line 4: t_s 0.001 is not after the previous row's 0.002"),
    ("t_s,u_V\n0,1\n0,2\n", "line 3: t_s 0 is not after"),
    ("t_s,u_V\n0,1\n0.001,12.5\n", "line 3: u_V 12.5 is outside 0..12 V"),
    ("t_s,u_V\n0,-1\n", "line 2: u_V -1 is outside"),
    ("t_s,u_V\n0\n", "line 2: 1 columns, the header has 2"),
])
def test_a_bad_file_is_one_error_naming_it_and_the_problem(tmp_path, text, problem):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(BadFileError) as err:
        load_input_file(path)
    assert err.value.path == str(path) and problem in err.value.problem, err.value.problem
    assert "\n" not in str(err.value)


def test_a_missing_or_binary_file_is_a_bad_file(tmp_path):
    with pytest.raises(BadFileError, match="cannot read the input file"):
        load_input_file(tmp_path / "none.csv")
    binary = tmp_path / "u.bin"
    binary.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(BadFileError, match="cannot read the input file"):
        load_input_file(binary)
