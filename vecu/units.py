"""Unit conversions, each defined once and named by direction (SI inside, DBC units on the bus).

The factors are exact constants so that `x * FACTOR` is the one way each conversion is computed
(the golden trace depends on the rounding of these very products).
"""

from __future__ import annotations

import math
from typing import Any

RAD_PER_DEG = math.pi / 180.0  # deg -> rad: x_rad = x_deg * RAD_PER_DEG
DEG_PER_RAD = 180.0 / math.pi  # rad -> deg: x_deg = x_rad * DEG_PER_RAD
MPS_PER_KMH = 1.0 / 3.6  # km/h -> m/s: v_mps = v_kmh * MPS_PER_KMH
KMH_PER_MPS = 3.6  # m/s -> km/h
KELVIN_AT_0_DEGC = 273.15  # degC -> K: T_K = T_degC + KELVIN_AT_0_DEGC
MG_PER_KG = 1e6  # kg -> mg
PA_PER_KPA = 1000.0  # kPa -> Pa
G_MPS2 = 9.81  # standard gravity used by the vehicle models, m/s^2


def deg_to_rad(x: float) -> float:
    return x * RAD_PER_DEG


def rad_to_deg(x: float) -> float:
    return x * DEG_PER_RAD


def kmh_to_mps(x: float) -> float:
    return x * MPS_PER_KMH


def mps_to_kmh(x: float) -> float:
    return x * KMH_PER_MPS


def degc_to_kelvin(x: float) -> float:
    return x + KELVIN_AT_0_DEGC


def kelvin_to_degc(x: float) -> float:
    return x - KELVIN_AT_0_DEGC


def affine(src: str, dst: str) -> tuple[float, float]:
    """(scale, offset) with x_dst = x_src * scale + offset between two unit names as DBCs and
    FMUs write them (pint's registry: degC, K, km/h, m/s, kPa, mV, ...); (1, 0) when either is
    empty or both are the same. ValueError naming the pair when pint cannot convert; ImportError
    without pint (an optional dependency: `vecu[fmu]`)."""
    if not src or not dst or src == dst:
        return 1.0, 0.0
    import pint

    ureg: Any = pint.UnitRegistry(autoconvert_offset_to_baseunit=True)
    try:
        zero = ureg.Quantity(0.0, src).to(dst).magnitude
        one = ureg.Quantity(1.0, src).to(dst).magnitude
    except Exception as exc:  # noqa: BLE001 - pint's undefined-unit and dimensionality errors
        raise ValueError(f"cannot convert {src!r} to {dst!r}: "
                         f"{str(exc).splitlines()[0]}") from None
    return float(one - zero), float(zero)
