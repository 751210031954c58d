"""The ECU's measurement variables as XCP sees them (A2L MEASUREMENTs): estimates, sigmas,
filter states, the sensor inputs as the ECU sees them, monitor states, DTC states and receive
counters. Each is read from the live node when it is sampled (UPLOAD or a DAQ event); a value
the ECU does not have yet (no sensor frame so far) reads NaN.

A value its type cannot hold never raises (it would stop the ECU's tick): it is saturated and
counted (`PackStats.saturated`, the summary's `xcp.values_saturated`): a float beyond FLOAT32's
range is sent as +-FLT_MAX (NaN and infinities are FLOAT32 values and pass as they are), an
integer out of its type's range as the type's limit, NaN (or None) in an integer as 0 (no value).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vecu.ecu.diagnostics import FLOAT, UBYTE, ULONG
from vecu.ecu.node import EcuNode
from vecu.xcp.memory import MEAS_BASE, TYPES

FLT_MAX = float(np.finfo(np.float32).max)


@dataclass
class PackStats:
    """Measurement values their type could not hold (saturated when packed)."""

    saturated: int = 0

SENSOR_UNITS = {"tps": "deg", "wheel": "km/h", "swa": "deg"}  # the monitors' physical units


@dataclass(frozen=True)
class Measurement:
    name: str
    unit: str
    code: str                 # struct code (memory.TYPES)
    read: Callable[[], Any]
    lo: float
    hi: float
    doc: str
    address: int = 0
    stats: PackStats = field(default_factory=PackStats, compare=False)

    @property
    def size(self) -> int:
        return TYPES[self.code][0]

    def pack(self) -> bytes:
        """The value now in its A2L type (saturated and counted when it does not fit)."""
        value = self.read()
        if self.code == FLOAT:
            try:
                return struct.pack("<f", math.nan if value is None else float(value))
            except OverflowError:  # finite beyond FLOAT32
                self.stats.saturated += 1
                return struct.pack("<f", FLT_MAX if value > 0 else -FLT_MAX)
        top = (1 << (8 * self.size)) - 1
        try:
            number = 0 if value is None else int(value)
        except (ValueError, OverflowError):  # NaN, +-inf
            self.stats.saturated += 1
            number = top if value == math.inf else 0
        if not 0 <= number <= top:
            self.stats.saturated += 1
            number = 0 if number < 0 else top
        return struct.pack("<" + self.code, number)


def ecu_measurements(node: EcuNode) -> list[Measurement]:
    """The node's variables, at consecutive addresses from MEAS_BASE (8-byte aligned)."""
    out: list[tuple[str, str, str, Callable[[], Any], float, float, str]] = []

    def add(name: str, unit: str, code: str, read: Callable[[], Any], lo: float, hi: float,
            doc: str) -> None:
        out.append((name, unit, code, read, lo, hi, doc))

    for fn in node.functions:  # each function's own variables (its `variables()`)
        for v in getattr(fn, "variables", list)():
            add(v.name, v.unit, v.code, v.read, v.lo, v.hi, v.doc)
    for name, mon in node.monitors.items():
        unit = SENSOR_UNITS.get(name, "1")
        add(f"monitor.{name}.value", unit, FLOAT, _reader(mon, "value"), -1000, 1000,
            f"{name} sensor as the ECU sees it: last valid frame's value ({unit})")
        add(f"monitor.{name}.status", "1", UBYTE, _reader(mon, "status", int), 0, 255,
            f"{name} sensor status (THR_TpsStatus codes)")
        add(f"monitor.{name}.dtc", "1", UBYTE, _reader(mon, "dtc", int), 0, 255,
            f"{name} DTC state")
    add("monitor.bus.dtc", "1", UBYTE, lambda: int(node.bus_dtc.state), 0, 255, "bus DTC state")
    rx = node.rx
    for counter in ("received", "accepted", "rejected", "crc_errors", "counter_errors",
                    "value_errors"):
        add(f"rx.{counter}", "1", ULONG, _reader(rx, counter), 0, 4294967295,
            f"frames {counter.replace('_', ' ')}")
    result = []
    address = MEAS_BASE
    stats = PackStats()  # one count over all of the node's measurements
    for name, unit, code, read, low, high, doc in out:
        size = TYPES[code][0]
        address = -(-address // size) * size
        result.append(Measurement(name, unit, code, read, low, high, doc, address, stats))
        address += size
    return result


def _reader(obj: Any, attr: str, conv: Callable[[Any], Any] | None = None) -> Callable[[], Any]:
    """A measurement's read function: obj.attr now (through conv)."""
    if conv is None:
        return lambda: getattr(obj, attr)
    return lambda: conv(getattr(obj, attr))
