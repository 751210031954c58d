"""The ECU's measurement variables as XCP sees them (A2L MEASUREMENTs): estimates, sigmas,
filter states, the sensor inputs as the ECU sees them, monitor states, DTC states and receive
counters. Each is read from the live node when it is sampled (UPLOAD or a DAQ event); a value
the ECU does not have yet (no sensor frame so far) reads NaN.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from vecu.ecu.node import EcuNode
from vecu.xcp.memory import MEAS_BASE, TYPES

FLOAT, UBYTE, ULONG = "f", "B", "I"  # FLOAT32_IEEE: fits a DAQ entry on CAN
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

    @property
    def size(self) -> int:
        return TYPES[self.code][0]

    def pack(self) -> bytes:
        value = self.read()
        if self.code == FLOAT:
            value = math.nan if value is None else float(value)
        else:
            value = 0 if value is None else max(0, min(int(value), (1 << (8 * self.size)) - 1))
        return struct.pack("<" + self.code, value)


def ecu_measurements(node: EcuNode) -> list[Measurement]:
    """The node's variables, at consecutive addresses from MEAS_BASE (8-byte aligned)."""
    out: list[tuple[str, str, str, Callable[[], Any], float, float, str]] = []

    def add(name: str, unit: str, code: str, read: Callable[[], Any], lo: float, hi: float,
            doc: str) -> None:
        out.append((name, unit, code, read, lo, hi, doc))

    thr = node.function("throttle")
    if thr is not None:
        est = thr.estimator  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
        mon = thr.monitor  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
        add("throttle.estimate_deg", "deg", FLOAT, lambda: est.theta_deg, -10, 100,
            "throttle angle estimate")
        add("throttle.sigma_deg", "deg", FLOAT, lambda: est.theta_std_deg, 0, 100,
            "throttle estimate standard deviation")
        add("throttle.angle_deg", "deg", FLOAT, lambda: thr.angle, -10, 100,  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            "throttle angle broadcast (sensor or estimate)")
        add("throttle.tps_deg", "deg", FLOAT, lambda: mon.value, -10, 100,
            "TPS angle as the ECU sees it (last valid frame)")
        add("throttle.source", "1", UBYTE, lambda: thr.source, 0, 1,  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            "0 sensor, 1 estimate")
        add("throttle.estimator_resets", "1", ULONG, lambda: est.resets, 0, 4294967295,
            "estimator resets")
    spd = node.function("speed")
    if spd is not None:
        kf = spd.kf  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
        add("speed.speed_mps", "m/s", FLOAT, lambda: kf.speed_mps, -100, 100,
            "vehicle speed estimate")
        add("speed.speed_std_mps", "m/s", FLOAT, lambda: kf.speed_std_mps, 0, 100,
            "vehicle speed standard deviation")
        add("speed.accel_mps2", "m/s^2", FLOAT, lambda: kf.accel_mps2, -50, 50,
            "longitudinal acceleration estimate")
        add("speed.offset_mps2", "m/s^2", FLOAT, lambda: kf.offset_mps2, -50, 50,
            "accelerometer offset state")
        add("speed.mode", "1", UBYTE, lambda: spd.mode, 0, 3,  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            "0 normal, 1 standstill, 2 ABS, 3 coast")
    ste = node.function("steering")
    if ste is not None:
        add("steering.angle_deg", "deg", FLOAT, lambda: ste.angle, -1000, 1000,  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            "steering-wheel angle broadcast (sensor or estimate)")
        add("steering.source", "1", UBYTE, lambda: ste.source, 0, 1,  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            "0 sensor, 1 estimate")
    man = node.function("manifold")
    if man is not None:
        for i, (name, unit, lo, hi, doc) in enumerate((
                ("p_im_kpa", "kPa", 0, 200, "manifold pressure estimate"),
                ("t_im_k", "K", 200, 400, "manifold temperature estimate"),
                ("cac_kg", "kg", 0, 0.002, "cylinder air charge"),
                ("cac_pred6_kg", "kg", 0, 0.002, "cylinder air charge predicted 6 events ahead")),
                start=1):
            add(f"manifold.{name}", unit, FLOAT,
                _element(man, i),
                lo, hi, doc)
        add("manifold.events", "1", ULONG, lambda: man.events, 0, 4294967295,  # type: ignore[attr-defined]  # a family attribute, not on the EcuFunction protocol
            "engine events filtered")
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
    for field in ("received", "accepted", "rejected", "crc_errors", "counter_errors",
                  "value_errors"):
        add(f"rx.{field}", "1", ULONG, _reader(rx, field), 0, 4294967295,
            f"frames {field.replace('_', ' ')}")
    result = []
    address = MEAS_BASE
    for name, unit, code, read, low, high, doc in out:
        size = TYPES[code][0]
        address = -(-address // size) * size
        result.append(Measurement(name, unit, code, read, low, high, doc, address))
        address += size
    return result


def _reader(obj: Any, attr: str, conv: Callable[[Any], Any] | None = None) -> Callable[[], Any]:
    """A measurement's read function: obj.attr now (through conv)."""
    if conv is None:
        return lambda: getattr(obj, attr)
    return lambda: conv(getattr(obj, attr))


def _element(fn: Any, i: int) -> Callable[[], Any]:
    """Element i of a function's last output tuple (None before its first)."""
    return lambda: None if fn.last is None else fn.last[i]
