"""vecu.units.affine: the unit conversion a binding between a DBC signal and a model variable
makes (pint), checked against vecu's own exact constants."""

from __future__ import annotations

import pytest

from vecu.units import KELVIN_AT_0_DEGC, MPS_PER_KMH, RAD_PER_DEG, affine

pytest.importorskip("pint")


@pytest.mark.parametrize("src, dst, scale, offset", [
    ("degC", "K", 1.0, KELVIN_AT_0_DEGC), ("K", "degC", 1.0, -KELVIN_AT_0_DEGC),
    ("km/h", "m/s", MPS_PER_KMH, 0.0), ("deg", "rad", RAD_PER_DEG, 0.0),
    ("mV", "V", 1e-3, 0.0), ("kPa", "Pa", 1e3, 0.0), ("V", "V", 1.0, 0.0), ("", "V", 1.0, 0.0),
])
def test_affine_matches_the_exact_constants(src, dst, scale, offset):
    got = affine(src, dst)
    assert got == pytest.approx((scale, offset), rel=1e-12, abs=1e-12)


def test_an_impossible_conversion_names_both_units():
    with pytest.raises(ValueError, match="cannot convert 'V' to 'm'"):
        affine("V", "m")
