"""Unit conversions, each defined once and named by direction (SI inside, DBC units on the bus).

The factors are exact constants so that `x * FACTOR` is the one way each conversion is computed
(the golden trace depends on the rounding of these very products).
"""

from __future__ import annotations

import math

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
