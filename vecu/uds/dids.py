"""Data identifiers (0x22 / 0x2E / 0x2F): the ECU's identification, live estimates and sensor
statuses, one writable calibration and the sensor values a tester may override.

Every number is an integer on the wire, big-endian: physical = raw * scale. "Not available"
(no frame yet) is all ones for an unsigned DID and the most negative value for a signed one.
docs/uds.md has the table (`did_table()` prints it).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, replace

from vecu.ecu.node import EcuNode
from vecu.ecu.sensor_monitor import SensorMonitor
from vecu.uds.config import UdsConfig
from vecu.units import DEG_PER_RAD, KELVIN_AT_0_DEGC, MG_PER_KG, MPS_PER_KMH

SW_VERSION = "vecu-0.1.0-uds1"
Reader = Callable[[], "float | None | bytes"]


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


def _ascii(text: str) -> Callable[[], bytes]:
    data = text.encode("ascii", "replace")
    return lambda: data


def _status(mon: SensorMonitor) -> Callable[[], float]:
    return lambda: float(int(mon.status))


def build_dids(node: EcuNode, config: UdsConfig, now_ns: Callable[[], int],
               session: Callable[[], int]) -> dict[int, Did]:
    """Every DID of this ECU: identification, then one group per function it runs."""
    dids = [
        Did(0xF190, "VIN", f"{len(config.vin)}s", 1, "ASCII", _ascii(config.vin)),
        Did(0xF195, "software version", f"{len(SW_VERSION)}s", 1, "ASCII", _ascii(SW_VERSION)),
        Did(0xF18C, "ECU serial number", f"{len(config.serial)}s", 1, "ASCII",
            _ascii(config.serial)),
        Did(0xF186, "active diagnostic session", "B", 1, "", lambda: float(session())),
        Did(0x0001, "ECU time since start", "I", 1, "ms", lambda: now_ns() // 1_000_000),
        # the host's doing, not a sensor's (a live bus): in a DTC's snapshot they tell a
        # stalled ECU or sender from a silent sensor
        Did(0x0002, "ECU not running since start (skipped base ticks)", "I", 1, "ms",
            lambda: node.host.stalled_ns // 1_000_000),
        Did(0x0003, "sensor frames' sender: ticks its host skipped (PLANT_Host)", "H", 1, "",
            lambda: float(node.host.sender_skipped)),
        Did(0x0004, "sensor frames' sender: ticks its host delayed (PLANT_Host)", "H", 1, "",
            lambda: float(node.host.sender_late)),
    ]
    thr = node.function("throttle")
    if thr is not None:
        mon: SensorMonitor = thr.monitor  # type: ignore[attr-defined]  # the throttle function (EcuFunction is the common base)
        est = thr.estimator  # type: ignore[attr-defined]  # as above

        def set_margin(v: float, m: SensorMonitor = mon) -> None:
            m.cfg = replace(m.cfg, plaus_margin=v)

        dids += [
            Did(0x0100, "throttle angle (broadcast)", "H", 0.01, "deg", lambda: thr.angle),
            Did(0x0101, "throttle angle estimate", "H", 0.01, "deg", lambda: est.theta_deg),
            Did(0x0102, "throttle estimate std", "H", 0.01, "deg", lambda: est.theta_std_deg),
            Did(0x0103, "throttle source (0 sensor, 1 estimate)", "B", 1, "",
                lambda: float(thr.source)),
            Did(0x0104, "TPS voltage (last valid)", "H", 0.0001, "V", lambda: mon.raw,
                io=("TPS_Sensor", "TPS_Voltage")),
            Did(0x0105, "TPS status", "B", 1, "", _status(mon)),
            Did(0x0110, "TPS plausibility margin (ecu.throttle.tps_monitor.plaus_margin)",
                "H", 0.01, "deg", lambda: mon.cfg.plaus_margin, write=set_margin),
        ]
    mfd = node.function("manifold")
    if mfd is not None:
        def last(i: int, scale: float = 1.0, offset: float = 0.0) -> Reader:
            return lambda: (None if mfd.last is None  # type: ignore[attr-defined]  # the manifold function
                            else mfd.last[i] * scale + offset)  # type: ignore[attr-defined]  # as above

        dids += [
            Did(0x0200, "manifold pressure", "H", 0.01, "kPa", last(1)),
            Did(0x0201, "manifold temperature", "h", 0.01, "degC",
                last(2, offset=-KELVIN_AT_0_DEGC)),
            Did(0x0202, "cylinder air charge", "H", 0.1, "mg", last(3, MG_PER_KG)),
            Did(0x0203, "cylinder air charge, 6 events ahead", "H", 0.1, "mg",
                last(4, MG_PER_KG)),
        ]
    spd = node.function("speed")
    if spd is not None:
        kf, wmon = spd.kf, spd.monitor  # type: ignore[attr-defined]  # the speed function
        dids += [
            Did(0x0300, "vehicle speed", "H", 0.01, "km/h", lambda: kf.speed_mps / MPS_PER_KMH),
            Did(0x0301, "vehicle acceleration", "h", 0.001, "m/s^2", lambda: kf.accel_mps2),
            Did(0x0302, "wheel speed (last valid)", "H", 0.01, "km/h", lambda: wmon.value,
                io=("ESC_Motion", "ESC_WheelSpeed")),
            Did(0x0303, "wheel-speed sensor status", "B", 1, "", _status(wmon)),
            Did(0x0304, "speed filter mode (0 normal, 1 standstill, 2 ABS, 3 coast)", "B", 1,
                "", lambda: float(spd.mode)),  # type: ignore[attr-defined]  # as above
        ]
    ste = node.function("steering")
    if ste is not None:
        ukf, smon = ste.ukf, ste.monitor  # type: ignore[attr-defined]  # the steering function
        dids += [
            Did(0x0400, "steering-wheel angle (broadcast)", "h", 0.05, "deg",
                lambda: ste.angle),  # type: ignore[attr-defined]  # as above
            Did(0x0401, "steering-wheel angle estimate", "h", 0.05, "deg",
                lambda: ukf.swa_rad * DEG_PER_RAD),
            Did(0x0402, "side-slip angle estimate", "h", 0.01, "deg",
                lambda: ukf.side_slip_rad * DEG_PER_RAD),
            Did(0x0403, "steering-wheel angle sensor (last valid)", "h", 0.05, "deg",
                lambda: smon.value, io=("SWA_Sensor", "SWA_Angle")),
            Did(0x0404, "steering-wheel angle sensor status", "B", 1, "", _status(smon)),
        ]
    return {d.did: d for d in dids}


# the freeze frame stored with a DTC at confirmation (those of them the ECU has)
SNAPSHOT_DIDS = (0x0001, 0x0002, 0x0003, 0x0004, 0x0100, 0x0101, 0x0104, 0x0105, 0x0300,
                 0x0400, 0x0403)


def did_table(dids: dict[int, Did]) -> str:
    """The DIDs as a Markdown table (docs/uds.md)."""
    rows = ["| DID | name | bytes | encoding | unit | access |", "|---|---|---|---|---|---|"]
    for d in sorted(dids.values(), key=lambda d: d.did):
        enc = "ASCII" if d.fmt.endswith("s") else (
            f"{'signed' if d.fmt.islower() else 'unsigned'} x {d.scale:g}")
        access = "read" + (", write (0x2E)" if d.write else "") + (
            f", IO control (0x2F: {d.io[0]}.{d.io[1]})" if d.io else "")
        rows.append(f"| 0x{d.did:04X} | {d.name} | {d.size} | {enc} | {d.unit} | {access} |")
    return "\n".join(rows)
