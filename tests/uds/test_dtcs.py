"""J2012 display codes of the functions' DTCs; the documented security key algorithm."""

from __future__ import annotations

from vecu.ecu.speed_function import DTCS as SPEED_DTCS
from vecu.ecu.steering_function import DTCS as STEERING_DTCS
from vecu.ecu.throttle_function import DTCS as THROTTLE_DTCS
from vecu.uds.dtcs import BUS_DTC
from vecu.uds.security import key_from_seed


def test_dtc_numbers_read_as_their_j2012_codes():
    DTC_TABLE = (*THROTTLE_DTCS, *SPEED_DTCS, *STEERING_DTCS, BUS_DTC)
    codes = {d.code for d in DTC_TABLE}
    assert {"P0122-00", "P0123-00", "P0121-00", "P0120-87", "C0035-87", "C0460-83",
            "U0001-00"} <= codes
    assert len({d.number for d in DTC_TABLE}) == len(DTC_TABLE)


def test_the_documented_key_algorithm():
    assert key_from_seed(bytes(4)) == bytes.fromhex("22A1C7BA")  # rotl7(0x56454355) + 0x1D0F
    assert key_from_seed(bytes.fromhex("56454355")) == bytes.fromhex("00001D0F")
