"""Identification intervals that cover (issue 30 item 4): over 20 simulated excitations of a
throttle whose mode-3 b is 15 % above Table I, each fitted parameter's 95 % interval holds the
true value in >= 17 of the traces from 180 s on (the length below which the report calls modes
1-2 intervals indicative); on 60 s traces every mode-3 parameter does (modes 1 and 2 do not: a
strict xfail), and the 15 % change of mode3.b is recovered within 3 %.

The traces are the plant's own compiled ticks (vecu.plant.throttle.ThrottlePlant.ticks, as
`vecu excite throttle` records them, without the CAN round trip) at the paper's noise (alpha = 1);
each fit is the full `identify_throttle` without the switching-angle profile (flat on these
traces: the start's 8, 16 deg are the truth). Needs the numba kernels: under plain Python a fit
takes minutes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vecu import kernels
from vecu.ident.report import SHORT_TRACE_S, interval_note
from vecu.ident.throttle import NAMES, identify_throttle
from vecu.ident.trace import ThrottleData
from vecu.models.sensors import TpsCalibration
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel
from vecu.plant.throttle import InputConfig, InputGenerator, ThrottlePlant, ThrottlePlantConfig
from vecu.rng import rng_streams

SECONDS = 60
SEEDS = range(20)
B_CHANGE = 1.15
TRUE = dataclasses.replace(PAPER_THROTTLE, mode3=dataclasses.replace(
    PAPER_THROTTLE.mode3, b=PAPER_THROTTLE.mode3.b * B_CHANGE))

pytestmark = pytest.mark.skipif(not kernels.numba_available(),
                                reason="20 identifications need the numba kernels")


def excitation(model: ThrottleModel, seconds: float, seed: int) -> ThrottleData:
    """u, wattmeter and TPS angle at 1 kHz from the plant driven by the Section III-B input."""
    n = int(seconds * 1000)
    rngs = rng_streams(seed, ("throttle.input", "throttle.plant"))
    u = np.asarray(InputGenerator(InputConfig(), rngs["throttle.input"]).take(n), dtype=float)
    cal = TpsCalibration()
    with kernels.using("numba"):
        out = ThrottlePlant(ThrottlePlantConfig(model=model), rngs["throttle.plant"]).ticks(u, cal)
    theta = np.array([cal.angle(v) for v in out[:, 4]])
    return ThrottleData(f"seed {seed}", u, out[:, 3].copy(), theta)


def truth(name: str) -> float:
    mode, param = name.split(".")
    return float(getattr(TRUE.modes[int(mode[-1]) - 1], param))


@pytest.fixture(scope="module")
def fits():
    with kernels.using("numba"):
        return [identify_throttle(excitation(TRUE, SECONDS, seed), fit_bounds=False)
                for seed in SEEDS]


@pytest.fixture(scope="module")
def fits_3min():
    """The same 20 seeds, 180 s each: the length from which `vecu identify throttle` gives its
    intervals without the short-trace note (vecu.ident.report.SHORT_TRACE_S)."""
    with kernels.using("numba"):
        return [identify_throttle(excitation(TRUE, SHORT_TRACE_S, seed), fit_bounds=False)
                for seed in SEEDS]


def _coverage(fits) -> dict[str, tuple[int, int]]:
    """Per parameter over the traces: (fitted intervals that missed the truth, fitted). A trace
    where the parameter was not identifiable gives no interval, so no miss."""
    out: dict[str, tuple[int, int]] = {}
    for fit in fits:
        for e in fit.estimates:
            if e.ci95 is not None:
                missed, fitted = out.get(e.name, (0, 0))
                out[e.name] = (missed + (abs(e.value - truth(e.name)) > e.ci95), fitted + 1)
    return out


def test_each_fitted_mode3_parameter_is_covered_in_17_of_20(fits) -> None:
    """Mode 3 (the valve above 16 deg, 80 % of the samples, where b was changed): at most 3 of
    20 fitted intervals miss, for every parameter; mode3.b and a33 fitted on every trace. Modes 1
    and 2 at least 13 of 20 (their shortfall: the next test)."""
    cov = _coverage(fits)
    assert cov["mode3.b"][1] == len(SEEDS) and cov["mode3.a33"][1] == len(SEEDS)
    assert {n.split(".")[1] for n in cov} <= set(NAMES)
    report = {n: f"{f - m}/{f} covered" for n, (m, f) in cov.items()}
    for name, (missed, _) in cov.items():
        assert missed <= (3 if name.startswith("mode3.") else 7), report


@pytest.mark.xfail(strict=True, reason="modes 1 and 2: mode2.a22 13/20, mode2.a23 14/20; too-narrow "
                   "intervals (estimates scatter 2.0-2.2x the reported sigma), not bias "
                   "(docs/reproduction.md, 'Identification')")
def test_each_fitted_mode1_mode2_parameter_is_covered_in_17_of_20(fits) -> None:
    """The issue's bound for the valve below 16 deg on 60 s traces: not met (strict: passing
    flags it); such a trace's report says its modes 1-2 intervals are indicative only, and from
    180 s they cover (test_every_fitted_parameter_is_covered_in_17_of_20_from_3_min)."""
    for name, (missed, _) in _coverage(fits).items():
        assert missed <= 3, name


def test_every_fitted_parameter_is_covered_in_17_of_20_from_3_min(fits_3min) -> None:
    """The issue's bound for every parameter of every mode, on traces as long as the report asks
    for (>= 180 s): at most 3 of 20 fitted intervals miss (measured: 17/18 .. 20/20)."""
    cov = _coverage(fits_3min)
    assert all(cov[f"mode{m}.{p}"][1] >= 17 for m in (1, 2, 3) for p in ("b", "a33"))
    report = {n: f"{f - m}/{f} covered" for n, (m, f) in cov.items()}
    assert all(missed <= 3 for missed, _ in cov.values()), report
    assert all(interval_note(fit) is None for fit in fits_3min)


def test_a_15_percent_change_of_mode3_b_is_recovered_within_3_percent(fits) -> None:
    """From 60 s: the estimate of the raised mode3.b within 3 % of the truth on seed 2 (the
    issue's case) and in the median over the 20 traces, and every estimate far from Table I's
    value (the change is seen, not the start kept)."""
    b = [next(e for e in fit.estimates if e.name == "mode3.b") for fit in fits]
    err = np.array([e.value / truth("mode3.b") - 1.0 for e in b])
    assert abs(err[2]) < 0.03
    assert np.median(np.abs(err)) < 0.03
    assert all(e.value > PAPER_THROTTLE.mode3.b * 1.07 for e in b)
