"""One validity state for every estimate the ECU shows: the CAN broadcast (the `*_Validity`
signals of dbc/vecu.dbc, one value table), the UDS DIDs (`0x0n0F`, one byte) and the replay
scoring (vecu.replay.scoring) read the same codes.

0 init: the filter has not been initialised from its first measurements; the value and its
sigma mean nothing (an all-zero frame reads as init, never as valid). 1 valid. 2 degraded: a
usable estimate with an honest, larger sigma (a substitute for a faulty sensor, coasting without
a measurement, a state that is not observable at standstill). 3 invalid: do not use.
"""

from __future__ import annotations

import enum


class Validity(enum.IntEnum):
    INIT = 0
    VALID = 1
    DEGRADED = 2
    INVALID = 3


# the members as module constants for the per-tick code (an enum class attribute costs ~65 ns)
INIT, VALID, DEGRADED, INVALID = (int(v) for v in Validity)
SCORED = frozenset({VALID, DEGRADED})  # what accuracy scoring counts; init / invalid are skipped
VALUE_TABLE = {int(v): v.name.lower() for v in Validity}  # = the DBC's VAL_ tables
