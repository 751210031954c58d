"""`vecu run --gateway`: vecu's estimates routed onto a second bus with another database on the
simulated clock, every routed frame in the log checked against the source frame it came from
(decoded by cantools), E2E re-protection checked by autosar-e2e, and reruns byte-identical."""

from __future__ import annotations

import os
import subprocess
import sys

import can
import cantools
import e2e as autosar_e2e
import pytest

from vecu.codec import builtin_dbc_path
from vecu.gateway.routes_config import load_routing_config
from vecu.gateway.sim import run_with_gateway
from vecu.runner import RunConfig

from .routing_setup import DATA, write_config

VECU_DB = cantools.database.load_file(str(builtin_dbc_path()))
BODY = cantools.database.load_file(str(DATA / "body.dbc"))
ENV = {**os.environ, "VECU_KERNELS": "python"}


@pytest.fixture(scope="module")
def routed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("routed")
    routing = load_routing_config(write_config(tmp))
    log = tmp / "run.log"
    result = run_with_gateway(RunConfig(duration_s=1.0, kill_tps_at_s=0.5, log_path=str(log)), routing)
    return log, result


def test_every_routed_frame_carries_its_source_values(routed):
    log, result = routed
    latest: dict[int, bytes] = {}
    seen = {0x420: 0, 0x500: 0, 0x510: 0}
    with can.LogReader(str(log)) as reader:
        for msg in reader:
            if msg.channel == "powertrain":
                latest[msg.arbitration_id] = bytes(msg.data)
                continue
            assert msg.channel == "vehicle"
            seen[msg.arbitration_id] += 1
            data = bytes(msg.data)
            if msg.arbitration_id == 0x420:  # ID translated, payload untouched
                assert data == latest[0x220]
            elif msg.arbitration_id == 0x500:
                got = BODY.decode_message(0x500, data, decode_choices=False)
                speed = VECU_DB.decode_message(0x220, latest[0x220])["SPD_VehSpeed"]
                thr = VECU_DB.decode_message(0x200, latest[0x200], decode_choices=False)
                assert got["VEH_Speed"] == pytest.approx(min(speed / 3.6, 50.0), abs=0.0026)
                assert got["VEH_Throttle"] == pytest.approx(min(thr["THR_Angle"], 100),
                                                            abs=0.0126)
                src_name = VECU_DB.get_message_by_frame_id(0x200).get_signal_by_name(
                    "THR_Source").choices[thr["THR_Source"]]
                assert BODY.get_message_by_frame_id(0x500).get_signal_by_name(
                    "VEH_Source").choices[got["VEH_Source"]] == src_name
                assert autosar_e2e.p11.e2e_p11_check(bytearray(data), 0x421)
            else:
                got = BODY.decode_message(0x510, data)
                yaw = VECU_DB.decode_message(0x130, latest[0x130])["LAT_YawRate"]
                assert got["VEH_Page"] == 2
                assert got["VEH_Yaw"] == pytest.approx(yaw, abs=0.026)
    # 1 s: the translated route at most every 20 ms, VEH_Dynamics on its 20 ms cycle
    assert seen[0x420] == 50 and seen[0x500] == 50 and seen[0x510] > 10
    routes = result.summary["gateway"]["routes"]
    assert routes["routes[1] powertrain->vehicle"]["out"] == 50
    assert all(r["latency_us"]["max"] in (0.0, None) for r in routes.values())  # delay 0


def test_the_cli_run_is_byte_identical_across_reruns(tmp_path):
    path = write_config(tmp_path)
    logs = []
    for n in range(2):
        log = tmp_path / f"run{n}.log"
        done = subprocess.run([sys.executable, "-m", "vecu", "run", "--duration", "0.5",
                               "--gateway", str(path), "--log", str(log)], capture_output=True,
                              text=True, env=ENV, check=False, timeout=120)
        assert done.returncode == 0, done.stderr
        assert "gateway routes[1] powertrain->vehicle: in 750, out 25" in done.stdout
        logs.append(log.read_bytes())
    assert logs[0] == logs[1] and b" vehicle 500#" in logs[0]


def test_a_bad_gateway_file_is_one_line_before_the_run(tmp_path):
    path = write_config(tmp_path, '[buses.a]\ndbc = ["vecu"]\n[[routes]]\nfrom = "a"\nto = "b"\n'
                                  'ids = [1]\n')
    done = subprocess.run([sys.executable, "-m", "vecu", "run", "--gateway", str(path), "--log",
                           str(tmp_path / "x.log")], capture_output=True, text=True, env=ENV,
                          check=False, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip() == (f"vecu: error: {path}: key 'routes[0].to': unknown bus 'b' "
                                   "(buses: a)")
    assert not (tmp_path / "x.log").exists()
    done = subprocess.run([sys.executable, "-m", "vecu", "run", "--gateway",
                           str(write_config(tmp_path)), "--channel", "x"], capture_output=True,
                          text=True, env=ENV, check=False, timeout=120)
    assert done.returncode == 2 and done.stderr.strip() == (
        "vecu: error: --gateway runs the buses its file names: no --interface or --channel")


def test_number_channel_formats_number_the_buses(tmp_path):
    """ASC and BLF keep channels as numbers: the buses' places in the file, 1 and 2."""
    routing = load_routing_config(write_config(tmp_path))
    for suffix in (".asc", ".blf"):
        log = tmp_path / f"run{suffix}"
        run_with_gateway(RunConfig(duration_s=0.1, kill_tps_at_s=None, log_path=str(log)), routing)
        with can.LogReader(str(log)) as reader:
            ids = {(m.channel, m.arbitration_id) for m in reader}
        assert (1, 0x220) in ids and (2, 0x500) in ids and (2, 0x220) not in ids

