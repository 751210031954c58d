"""What an ECU function shows its diagnostic servers: UDS data identifiers (Did, read / written /
IO-controlled by vecu.uds), the DTCs of the sensors it diagnoses (DtcSpec, vecu.uds.dtcs),
measurement variables (Variable, sampled by vecu.xcp) and the calibration subtrees it takes
mid-run (vecu.xcp.calibration). Each function lists its own (`dids()`, `dtcs()`,
`variables()`, `calibrations()`); the servers iterate the node's functions.

A DID's number is an integer on the wire, big-endian: physical = raw * scale. "Not available"
(no frame yet) is all ones for an unsigned DID and the most negative value for a signed one.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from vecu.ecu.sensor_monitor import SensorMonitor, SensorStatus

Reader = Callable[[], "float | None | bytes"]
FLOAT, UBYTE, ULONG = "f", "B", "I"  # a Variable's struct code; FLOAT32_IEEE fits a DAQ entry


@dataclass(frozen=True)
class Did:
    did: int
    name: str
    fmt: str          # struct code of one value ("B", "H", "h", "I") or "<n>s" (ASCII)
    scale: float
    unit: str
    read: Reader
    write: Callable[[float], None] | None = None  # 0x2E: a calibration (extended, unlocked)
    io: tuple[str, str] | None = None             # 0x2F: (message, signal) the ECU sees

    @property
    def size(self) -> int:
        return struct.calcsize(">" + self.fmt)

    @property
    def limits(self) -> tuple[int, int, int]:
        """(lowest, highest raw value, the 'not available' raw value)."""
        bits = 8 * self.size
        if self.fmt.islower():  # signed
            return -(1 << (bits - 1)) + 1, (1 << (bits - 1)) - 1, -(1 << (bits - 1))
        return 0, (1 << bits) - 2, (1 << bits) - 1

    def encode(self, value: float | None | bytes) -> bytes:
        if self.fmt.endswith("s"):
            return bytes(value or b"").ljust(self.size, b" ")[:self.size]  # type: ignore[arg-type]  # a string DID: bytes or None
        lo, hi, na = self.limits
        if value is None or not math.isfinite(value):  # type: ignore[arg-type]  # a numeric DID: float or None
            raw = na
        else:
            raw = min(max(round(value / self.scale), lo), hi)  # type: ignore[operator]  # a numeric DID: float
        return struct.pack(">" + self.fmt, raw)

    def decode(self, data: bytes) -> float | None:
        """The physical value of `size` bytes (None: not available); not for ASCII DIDs."""
        (raw,) = struct.unpack(">" + self.fmt, data)
        return None if raw == self.limits[2] else raw * self.scale

    def value(self) -> bytes:
        return self.encode(self.read())


@dataclass(frozen=True)
class DtcSpec:
    """One DTC: its SAE J2012 number, the monitor it reports ("tps", ... or "bus") and the
    monitor findings (SensorStatus) that set it."""

    number: int          # 3 bytes: J2012 code (2 bytes) and failure type byte
    source: str          # monitor name (a function's monitors() key) or "bus"
    findings: tuple[SensorStatus, ...]
    text: str

    @property
    def code(self) -> str:
        """The J2012 display form, e.g. P0122-00."""
        hi = self.number >> 16
        letter = "PCBU"[hi >> 6]
        mid, low = (self.number >> 8) & 0xFF, self.number & 0xFF
        return f"{letter}{(hi >> 4) & 3}{hi & 0xF:X}{mid:02X}-{low:02X}"


# a function's calibrations(): subtree path under ecu. -> how the function takes its new value
Calibrations = dict[str, Callable[[Any], None]]


@dataclass(frozen=True)
class Variable:
    """A measurement variable (an A2L MEASUREMENT): read from the live function when sampled;
    None reads as NaN (FLOAT) or 0."""

    name: str
    unit: str
    code: str  # FLOAT, UBYTE or ULONG
    read: Callable[[], Any]
    lo: float
    hi: float
    doc: str


def validity_did(did: int, name: str, read: Callable[[], int]) -> Did:
    """A function's validity DID (one byte, vecu.ecu.validity's codes: what its estimate
    message's *_Validity signal says)."""
    return Did(did, f"{name} (0 init, 1 valid, 2 degraded, 3 invalid)", "B", 1, "",
               lambda: float(read()))


def status_reader(mon: SensorMonitor) -> Callable[[], float]:
    """A DID reader of a sensor monitor's status code."""
    return lambda: float(int(mon.status))
