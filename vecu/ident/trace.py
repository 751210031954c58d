"""A throttle trace as 1 kHz arrays: input voltage u, wattmeter power y and valve angle theta.

Read from any python-can log (vecu's own DBC, or the user's with a signal map, as `vecu replay`):
the throttle inputs motor_voltage (u), motor_power (y) and tps_voltage (the position signal,
turned into degrees by the ECU's TPS law `ecu.throttle.calibration`). One sample per wattmeter
frame; the angle is the last TPS reading at or before it. A trace that cannot support a fit is a
BadFileError naming the file and what is missing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vecu.codec import DbcCodec
from vecu.errors import BadFileError
from vecu.functions import spec
from vecu.models.sensors import TpsCalibration
from vecu.replay.signal_map import identity_map, load_signal_map
from vecu.replay.source import TraceSource

MIN_SAMPLES = 3000  # 3 s at 1 kHz: fewer cannot pin down 29 parameters
MIN_U_STD_V = 0.2  # "no excitation": the input barely moves
MIN_THETA_RANGE_DEG = 5.0  # ... or the valve barely moves
SAMPLE_PERIOD_S = 1e-3


class TraceFitError(BadFileError):
    """A trace that cannot support the identification: TraceFitError(path, what is missing)."""


@dataclass(frozen=True)
class ThrottleData:
    """Samples k = 0..n-1 at 1 ms: u_k (V), y_k (W), theta_k (deg, from the TPS)."""

    path: str
    u: np.ndarray
    y: np.ndarray
    theta: np.ndarray

    @property
    def n(self) -> int:
        return int(self.u.size)


def read_throttle_trace(path: str | Path, dbc: tuple[str, ...] = (), signal_map: str | None = None,
                        tps: TpsCalibration | None = None, fmt: str | None = None,
                        max_samples: int | None = None) -> ThrottleData:
    """The throttle signals of a trace (see the module docstring); max_samples keeps the first
    ones. Raises TraceFitError / the replay's read errors (one line, naming the file)."""
    path = str(path)
    tps = tps or TpsCalibration()
    db = DbcCodec(list(dbc)) if dbc else DbcCodec()
    smap = load_signal_map(signal_map, db) if signal_map else identity_map(db)
    wanted = {m.name: m for m in smap.inputs if m.function == "throttle"}
    missing = [name for name in spec("throttle").inputs if name not in wanted]
    if missing:
        raise TraceFitError(path, f"the database has no {', '.join(missing)} signal for the "
                            "throttle (map it with --map MAP.toml: [throttle] motor_voltage, "
                            "motor_power, tps_voltage)")
    src = {(wanted[n].source_message, n) for n in wanted}
    by_msg: dict[str, list[str]] = {}
    for msg, name in src:
        by_msg.setdefault(msg, []).append(name)
    codecs = {db[msg].frame_id: (db[msg], names) for msg, names in by_msg.items()}
    u: list[float] = []
    y: list[float] = []
    th: list[float] = []
    last: dict[str, float] = {}
    source = TraceSource(path, fmt)
    for _, msg in source:
        hit = codecs.get(msg.arbitration_id)
        if hit is None:
            continue
        codec, names = hit
        try:
            values = codec.decode(msg.data)
        except Exception:  # noqa: BLE001, S112 - a frame the decoder cannot take is skipped
            continue
        for name in names:
            m = wanted[name]
            v = float(values[m.source_signal]) * m.factor + m.offset
            if np.isfinite(v):
                last[name] = v
        if "motor_power" in names and "tps_voltage" in last and "motor_voltage" in last:
            u.append(last["motor_voltage"])
            y.append(last["motor_power"])
            th.append(tps.angle(last["tps_voltage"]))
            if max_samples is not None and len(u) >= max_samples:
                break
    if source.error and not u:
        raise TraceFitError(None, source.error)  # it names the file
    data = ThrottleData(path, np.array(u), np.array(y), np.array(th))
    check_fit_support(data)
    return data


def check_fit_support(data: ThrottleData) -> None:
    """Raise TraceFitError when the data cannot support a fit: too short, no excitation."""
    if data.n < MIN_SAMPLES:
        raise TraceFitError(data.path, f"too short for an identification: {data.n} samples with "
                            f"motor voltage, wattmeter power and TPS angle (need >= "
                            f"{MIN_SAMPLES}, {MIN_SAMPLES * SAMPLE_PERIOD_S:g} s at 1 kHz)")
    u_std = float(np.std(data.u))
    if not u_std >= MIN_U_STD_V:
        raise TraceFitError(data.path, f"no excitation: the motor voltage hardly varies (std "
                            f"{u_std:.3g} V < {MIN_U_STD_V} V; record with `vecu excite throttle`)")
    span = float(np.ptp(data.theta))
    if not span >= MIN_THETA_RANGE_DEG:
        raise TraceFitError(data.path, f"no excitation: the valve angle spans only {span:.3g} deg "
                            f"(< {MIN_THETA_RANGE_DEG} deg)")
