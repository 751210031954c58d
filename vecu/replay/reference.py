"""The reference traces in traces/ and their golden estimate outputs.

    python -m vecu.replay.reference traces/          # regenerate traces and golden outputs
    python -m vecu.replay.reference traces/ --golden # golden outputs only (after an ECU change)

Native traces come from `vecu run --log` (plant + ECU + truth frames). The third-party trace puts
the same simulated vehicle on an OxTS RT-style database (cantools' test file vehicle.dbc, 29-bit
IDs): it is what a user's logger would record, and replays through traces/maps/oxts_rt.toml.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import can

from vecu.codec import TRUTH_DBC, DbcCodec, builtin_dbc_path
from vecu.config import RunConfig
from vecu.plant.lateral import LateralPart, simulate_lateral
from vecu.plant.lateral import ManoeuvreConfig as LateralManoeuvre
from vecu.plant.longitudinal import simulate_speed
from vecu.replay.engine import ReplayConfig, replay

G = 9.80665


@dataclass(frozen=True)
class ReferenceTrace:
    name: str           # file name in traces/
    description: str
    dbc: tuple[str, ...] = ()   # relative to traces/ (third-party traces)
    signal_map: str | None = None


NATIVE = {
    "drive_tps_dead.blf": ("all four functions, 3 s, seed 1, TPS dead at 1.5 s",
                           RunConfig(duration_s=3.0, seed=1, kill_tps_at_s=1.5)),
    "drive_swa_stuck.log.gz": (("all four functions, 3 s, seed 2, TPS offset +0.5 V at 1.0 s, "
                                "SWA sensor stuck at 1.2 s (candump -L, gzip)"),
                               RunConfig(duration_s=3.0, seed=2, kill_tps_at_s=1.0,
                                         fault="offset", fault_value=0.5, kill_swa_at_s=1.2,
                                         swa_fault="stuck")),
}
THIRD_PARTY = ReferenceTrace(
    "oxts_rt_drive.blf", "speed and lateral inputs on an OxTS RT-style DBC (vehicle.dbc from "
    "cantools' tests), 4 s, seed 7, with vecu truth frames", dbc=("dbc/vehicle.dbc",),
    signal_map="maps/oxts_rt.toml")


def references() -> list[ReferenceTrace]:
    return [ReferenceTrace(n, d) for n, (d, _) in NATIVE.items()] + [THIRD_PARTY]


def golden_path(traces_dir: Path, ref: ReferenceTrace) -> Path:
    return traces_dir / "golden" / (ref.name.split(".")[0] + ".estimates.log")


def replay_reference(traces_dir: Path, ref: ReferenceTrace, out: Path) -> dict:
    cfg = ReplayConfig(trace=str(traces_dir / ref.name),
                       dbc=tuple(str(traces_dir / d) for d in ref.dbc),
                       signal_map=str(traces_dir / ref.signal_map) if ref.signal_map else None,
                       out=str(out), progress=False)
    result = replay(cfg)
    if result.error:
        raise RuntimeError(result.error)
    return result.summary


def write_oxts_trace(path: Path, dbc_path: Path, seed: int, duration_s: float) -> None:
    """Longitudinal and lateral plants on OxTS RT messages: wheel-based speed (RT_SB_Speed) and
    accelerometer at 500 Hz, yaw rate and INS forward speed at 100 Hz; truth frames beside."""
    db = DbcCodec([dbc_path])
    truth = DbcCodec([builtin_dbc_path(TRUTH_DBC)])
    spd, acc = db["RT_SB_Speed"], db["RT_IMU06_Accel"]
    gyro, vel = db["RT_IMU06_Gyro_Rates"], db["RT_SB_INS_Vel_Body_Axes"]
    t_spd, t_lat = truth["TRUTH_Speed"], truth[LateralPart.truth_message]
    lon = simulate_speed(seed=seed)
    lat = simulate_lateral(seed, LateralManoeuvre(duration_s=max(duration_s + 1.0, 20.0)))
    deg = 180.0 / math.pi
    n = round(duration_s * 500)

    def zeros(fc):
        return {s: 0.0 for s in fc.ranges}

    with can.Logger(str(path)) as w:
        for k in range(n):
            ts = k * 0.002
            i = min(k, len(lon.v) - 1)
            j = min(k // 5, len(lat.t) - 1)
            frames = [
                spd.frame({**zeros(spd), "Validity_Speed": 1, "Speed": float(lon.wheel[i])}, ts),
                acc.frame({**zeros(acc), "Validity_Accel_Longitudinal": 1,
                           "Validity_Accel_Lateral": 1, "Accel_Longitudinal": lon.accel[i] / G,
                           "Accel_Lateral": lat.meas_ay[j] / G}, ts),
                t_spd.frame({"TRU_VehSpeed": lon.v[i] * 3.6, "TRU_VehAccel": lon.a[i]}, ts)]
            if k % 5 == 0:
                frames += [
                    gyro.frame({**zeros(gyro), "Validity_Gyro_Rate_Yaw": 1,
                                "Gyro_Rate_Yaw": lat.meas_r[j] * deg}, ts),
                    vel.frame({**zeros(vel), "Validity_INS_Vel_Forwards": 1,
                               "INS_Vel_Forwards_2D": float(lat.meas_vx[j])}, ts),
                    t_lat.frame({"TRU_SwAngle": lat.swa[j] * deg,
                                 "TRU_SideSlip": lat.beta[j] * deg}, ts)]
            for msg in frames:
                w.on_message_received(msg)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m vecu.replay.reference", description=__doc__)
    ap.add_argument("traces_dir", type=Path)
    ap.add_argument("--golden", action="store_true", help="only regenerate the golden outputs")
    args = ap.parse_args(argv)
    d: Path = args.traces_dir
    (d / "golden").mkdir(parents=True, exist_ok=True)
    if not args.golden:
        from vecu.runner import run
        for name, (_, cfg) in NATIVE.items():
            run(replace(cfg, log_path=str(d / name)))
        write_oxts_trace(d / THIRD_PARTY.name, d / THIRD_PARTY.dbc[0], seed=7, duration_s=4.0)
    for ref in references():
        s = replay_reference(d, ref, golden_path(d, ref))
        print(f"{ref.name}: {s['frames']['read']} frames -> {s['frames_written']} estimate frames",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
