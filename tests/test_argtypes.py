"""vecu/argtypes.py: the argparse types every numeric option uses (finite, in range, seeds)."""

from __future__ import annotations

import argparse

import pytest

from vecu import argtypes


@pytest.mark.parametrize("text,value", [("0", 0), ("7", 7), (str(2**63 - 1), 2**63 - 1)])
def test_seed_takes_what_a_scenario_file_can_hold(text: str, value: int) -> None:
    assert argtypes.seed(text) == value


@pytest.mark.parametrize("text", ["-1", str(2**63), "1.5", "nan", "", "0x10"])
def test_seed_refuses_negative_huge_and_non_integers(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="expected an integer in 0.."):
        argtypes.seed(text)


@pytest.mark.parametrize("parse,text", [
    (argtypes.finite, "nan"), (argtypes.finite, "inf"), (argtypes.finite, "-inf"),
    (argtypes.positive, "0"), (argtypes.positive, "-1"), (argtypes.non_negative, "-0.1"),
    (argtypes.noise_scale, "1e300"), (argtypes.noise_scale, "nan"),
    (argtypes.run_seconds, "0.0004"), (argtypes.run_seconds, "1e9"),
    (argtypes.tick_us, "-1"), (argtypes.tick_us, "2.5"), (argtypes.positive_int, "0"),
    (argtypes.bounded(0.0, 1.0, lo_open=True), "0"), (argtypes.finite, "x"),
])
def test_bounded_refuses_non_finite_and_out_of_range(parse, text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=f"expected .*, got '{text}'"):
        parse(text)


@pytest.mark.parametrize("parse,text,value", [
    (argtypes.finite, "-1e300", -1e300), (argtypes.positive, "1e-9", 1e-9),
    (argtypes.non_negative, "0", 0.0), (argtypes.noise_scale, "0.3", 0.3),
    (argtypes.run_seconds, "0.001", 0.001), (argtypes.run_seconds, "86400", 86400.0),
    (argtypes.tick_us, "1000", 1000), (argtypes.bounded(0.0, 1.0, lo_open=True), "1", 1.0),
])
def test_bounded_takes_the_range_ends(parse, text: str, value: float) -> None:
    got = parse(text)
    assert got == value and type(got) is type(value)


@pytest.mark.parametrize("text,value", [("none", None), ("half", "half"), ("2.5", 2.5)])
def test_kill_time(text: str, value) -> None:
    assert argtypes.kill_time(text) == value


@pytest.mark.parametrize("text", ["nan", "inf", "soon"])
def test_kill_time_refuses_non_finite(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        argtypes.kill_time(text)
