"""`vecu plant` + `vecu ecu` on a real kernel's vcan0, with can-utils and the kernel's ISO-TP as
the outside world (docs/live.md's SocketCAN recipes, each one run here).

One live session (module fixture): candump -L records the bus; the ECU and the plant start as a
user starts them (the plant with --rx-filter: kernel filters); while the plant runs, cangen adds
background traffic on an ID nobody owns and cansend sends an error frame, a frame on one of the
ECU's own IDs and the FI_Command that kills the TPS; afterwards a udsoncan tester over the
kernel's CAN_ISOTP (can-isotp's isotp.socket) reads the VIN, live DIDs and the TPS DTC, and
isotpsend / isotprecv read the VIN and send 4095-byte requests. The tests below check what each
part left behind. Behaviour, not timing: the emulated kernel runs Python ~20x slower (the ECU
skips ticks there and takes its frames late, from a large socket buffer)."""

from __future__ import annotations

import signal
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Any

import can
import pytest

from tests.socketcan.kernel import (
    CHANNEL,
    START_S,
    Processes,
    ecu_drained,
    isotp_request,
    kernel_isotp,
    needs_kernel,
    summary,
    tool,
    wait_for,
)

pytestmark = needs_kernel

PLANT_PARTS = ["--no-steering", "--no-manifold"]  # the throttle and speed functions: ~3 frames/ms
PLANT_S = 8.0  # the plant's run (wall clock); the tester's questions come after it
CANGEN_FRAMES = 1000
CANGEN_ID = 0x5A5  # in no DBC of vecu's
TPS_DEAD = "6F0#01010000"  # FI_Command: FI_Target 1 (tps), FI_Kind 1 (dead), FI_Value 0
FOREIGN_ECU_FRAME = "200#0000000000000000"  # ECU_ThrottleEstimate's ID, from another sender
ERROR_FRAME = "20000080#0000000000000000"  # CAN_ERR_FLAG | CAN_ERR_BUSERROR (controller report)
LONG_REQUEST = bytes([0x22]) + bytes(range(256)) * 15 + bytes(range(254))  # 4095 bytes
DTC_TPS = 0x012200


def _client(isotp_module: Any) -> Any:
    from udsoncan.client import Client
    from udsoncan.connections import IsoTPSocketConnection

    from tests.uds.sim import CLIENT_CONFIG

    addr = isotp_module.Address(isotp_module.AddressingMode.Normal_11bits, txid=0x7E0, rxid=0x7E8)
    conn = IsoTPSocketConnection(CHANNEL, addr)
    return Client(conn, config={**CLIENT_CONFIG, "dtc_snapshot_did_size": 2,
                                "request_timeout": 30.0, "p2_timeout": 10.0,
                                "p2_star_timeout": 30.0})


def _isotp_tools_request(payload: bytes) -> bytes:
    """isotprecv waits for one PDU on 0x7E8 while isotpsend sends `payload` on 0x7E0."""
    recv = subprocess.Popen(["isotprecv", "-s", "7E0", "-d", "7E8", CHANNEL],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(0.5)  # bound before the request goes out
        tool("isotpsend", "-s", "7E0", "-d", "7E8", CHANNEL, stdin=payload.hex(" "))
        out, err = recv.communicate(timeout=120)
    finally:
        if recv.poll() is None:
            recv.kill()
            recv.wait()
    assert recv.returncode == 0, err
    return bytes.fromhex(out.strip())


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> dict[str, Any]:
    import isotp

    out = tmp_path_factory.mktemp("vcan-live")
    procs = Processes(out)
    res: dict[str, Any] = {"out": out}
    bus = ["--interface", "socketcan", "--channel", CHANNEL, "--no-status", "--quiet"]
    try:
        # -r: a 64 MiB socket buffer, so a burst (ISO-TP blocks) is not lost while the emulated
        # guest gets to candump late
        procs.start("candump", ["candump", "-L", "-r", str(64 << 20), CHANNEL],
                    stdout=out / "candump.log")
        # under emulation the ECU takes frames slower than the plant sends them: its socket's
        # receive buffer holds the backlog (no frame may be lost, however slow the host)
        procs.vecu("ecu", "ecu", *bus, *PLANT_PARTS, "--summary", str(out / "ecu.json"),
                   "--ready-file", str(out / "ecu.ready"), "--sync-timeout", str(START_S),
                   "--duration", "1800", "--tps-timeout-cycles=1000", "--host-gap-ms=5000",
                   "--rx-buffer-mb", "256")
        procs.ready("ecu", out / "ecu.ready")
        procs.vecu("plant", "plant", *bus, *PLANT_PARTS, "--rx-filter",
                   "--summary", str(out / "plant.json"), "--ready-file", str(out / "plant.ready"),
                   "--duration", str(PLANT_S))
        procs.ready("plant", out / "plant.ready")
        # while the plant sends: the outside world's frames
        time.sleep(1.0)
        tool("cangen", CHANNEL, "-I", f"{CANGEN_ID:X}", "-L", "8", "-D", "i", "-g", "1",
             "-n", str(CANGEN_FRAMES), timeout_s=300)
        tool("cansend", CHANNEL, ERROR_FRAME)
        tool("cansend", CHANNEL, FOREIGN_ECU_FRAME)
        tool("cansend", CHANNEL, TPS_DEAD)
        plant = procs.procs["plant"]
        assert wait_for(lambda: plant.poll() is not None, START_S + PLANT_S), "plant ran on"
        res["rc"] = {"plant": plant.returncode}
        assert ecu_drained() == bytes([0x7E, 0x00])  # the ECU has taken every frame sent
        # a tester after the run: what the ECU found, through the kernel's ISO-TP
        with _client(isotp) as c:
            res["vin"] = c.read_data_by_identifier(0xF190).service_data.values[0xF190]
            live = c.read_data_by_identifier([0x0103, 0x0105]).service_data.values
            res["live"] = {f"{k:04X}": v for k, v in live.items()}
            dtcs = c.get_dtc_by_status_mask(0x08).service_data.dtcs
            res["confirmed"] = [(d.id, d.status.get_byte_as_int()) for d in dtcs]
        res["tools_vin"] = _isotp_tools_request(bytes([0x22, 0xF1, 0x90]))
        res["tools_long"] = _isotp_tools_request(LONG_REQUEST)
        res["socket_long"] = isotp_request(LONG_REQUEST)  # the kernel's ISO-TP, straight
        res["rc"]["ecu"] = procs.stop("ecu")
        # candump drops what is still queued in its socket when it stops: let it write it all
        wait_for(_stops_growing(out / "candump.log"), START_S, 0.5)
        procs.stop("candump", signal.SIGINT)
    finally:
        procs.close()
        res["stderr"] = {n: procs.stderr(n) for n in procs.procs}
    res["ecu"] = summary(out / "ecu.json")
    res["plant"] = summary(out / "plant.json")
    return res


def _stops_growing(path: Path):
    sizes: list[int] = []

    def check() -> bool:
        sizes.append(path.stat().st_size if path.exists() else -1)
        return len(sizes) >= 5 and len(set(sizes[-5:])) == 1

    return check


def _candump_counts(path: Path) -> Counter:
    with can.LogReader(str(path)) as reader:
        return Counter((m.arbitration_id, m.is_extended_id) for m in reader)


def _key(codec, name: str) -> tuple[int, bool]:
    m = codec[name]
    return (m.frame_id, m.is_extended)


def test_both_nodes_exit_cleanly(session):
    assert session["rc"] == {"plant": 0, "ecu": 0}, session["stderr"]
    assert session["plant"]["stopped_by"] == "duration"
    assert session["ecu"]["stopped_by"] == "SIGTERM"


def test_the_ecu_receives_every_plant_frame_and_none_as_its_own_echo(session):
    """The bug this suite was written for: python-can marks frames of another local process
    is_rx=False on SocketCAN, and the ECU dropped all of them as its own echo."""
    ecu, plant = session["ecu"], session["plant"]
    assert ecu["bus"]["own_echo"] == 0 and plant["bus"]["own_echo"] == 0
    assert ecu["bus"]["rx_errors"] == 0
    sent = plant["bus"]["tx_by_id"]
    assert set(sent) >= {"TPS_Sensor", "ETB_Wattmeter", "ESC_Motion"}, sent
    # per ID, what the ECU took from the bus (its start-up sync included) is what the plant sent
    taken = ecu["bus"]["rx_by_id"]
    for name, n in sent.items():
        assert taken.get(name) == n, (name, n, taken.get(name))
    rx = ecu["rx"]
    assert rx["accepted"] > 1000
    # rejected: cangen's unknown IDs and the error frame, nothing else (no DLC / E2E / value error)
    assert rx["rejected"] == rx["unknown_id"] + rx["error_frames"] == CANGEN_FRAMES + 1
    assert ecu["estimates"]["throttle"] > 100 and ecu["estimates"]["speed"] > 50


def test_candump_records_every_frame_both_nodes_sent(session):
    from vecu.codec import DbcCodec

    codec = DbcCodec()
    counts = _candump_counts(session["out"] / "candump.log")
    for who in ("plant", "ecu"):
        for name, n in session[who]["bus"]["tx_by_id"].items():
            key = (int(name, 16), False) if name.startswith("0x") else _key(codec, name)
            # 0x7E8: the ECU's UDS responses; ECU_ThrottleEstimate: cansend's one frame too
            foreign = int(name == "ECU_ThrottleEstimate")
            assert counts[key] == n + foreign, (who, name, n)
    assert counts[(CANGEN_ID, False)] == CANGEN_FRAMES


def test_kernel_filters_pass_the_plant_only_its_fault_commands(session):
    plant = session["plant"]
    assert plant["bus"]["rx_filter"] == ["0x6F0"]
    # the ECU's broadcast, cangen's traffic and the other frames never reached the plant
    assert plant["bus"]["rx_by_id"] == {"FI_Command": 1}
    assert plant["bus"]["fd"] is True  # vcan's MTU is CANFD_MTU: opened for CAN FD
    assert session["ecu"]["bus"]["rx_filter"] is None  # the ECU sees (and counts) everything


def test_background_traffic_is_counted_as_unknown_ids(session):
    rx = session["ecu"]["rx"]
    assert rx["unknown_id"] == CANGEN_FRAMES
    assert session["ecu"]["bus"]["rx_by_id"]["0x5A5"] == CANGEN_FRAMES


def test_an_error_frame_from_the_kernel_is_counted(session):
    assert session["ecu"]["rx"]["error_frames"] == 1
    assert session["ecu"]["bus"]["error_frames"] == 1
    # error frames pass any kernel filter (CAN_RAW_ERR_FILTER): the plant saw it too, and ignored it
    assert session["plant"]["bus"]["error_frames"] == 1


def test_a_frame_on_the_ecus_own_id_from_another_sender_is_counted_apart(session):
    bus = session["ecu"]["bus"]
    assert bus["foreign_own_id"] == 1 and bus["own_echo"] == 0


def test_cansend_fi_command_kills_the_tps_and_the_ecu_reports_it(session):
    plant, ecu = session["plant"], session["ecu"]
    kills = [e for e in plant["fault_events"] if e["source"] == "can"]
    assert [(e["target"], e["kind"]) for e in kills] == [("tps", "dead")]
    th = ecu["throttle"]
    assert th["detected_as"] == "range_low", th
    assert th["final_source"] == "estimate"
    assert any(d == DTC_TPS and status & 0x08 for d, status in session["confirmed"]), \
        session["confirmed"]


def test_udsoncan_over_the_kernels_isotp_reads_vin_and_live_dids(session):
    assert kernel_isotp()
    assert session["vin"] == "1VECU00SIM0000001"
    # after the kill: the estimate is broadcast, the TPS status is a fault
    assert session["live"]["0103"] == 1 and session["live"]["0105"] != 0


def test_isotpsend_and_isotprecv_read_the_vin(session):
    tools = session["tools_vin"]
    assert tools[:3] == bytes([0x62, 0xF1, 0x90]) and tools[3:] == b"1VECU00SIM0000001"


def test_4095_byte_requests_get_their_answer_not_silence(session):
    """ReadDataByIdentifier with 2047 DIDs (more than ecu.uds.max_dids_per_request): every frame
    of the request must get in (flow control the ECU can absorb), and ISO 14229 owes 7F 22 13."""
    assert session["tools_long"] == bytes([0x7F, 0x22, 0x13])
    assert session["socket_long"] == bytes([0x7F, 0x22, 0x13])
    uds = session["ecu"]["uds"]
    assert uds["frames_dropped"] == 0 and uds["transport_errors"] == 0


def test_vecu_replay_of_the_candump_recording_sees_the_same_bus(session, tmp_path):
    """candump's file goes back into vecu (the seconds around the kill, cut with python-can: a
    whole session takes minutes to replay under emulation): every plant frame decodes, nothing
    is rejected, and the replayed ECU finds the TPS dead as the live one did and broadcasts the
    estimate after it."""
    from vecu.cli import main as cli_main
    from vecu.codec import DbcCodec

    codec = DbcCodec()
    with can.LogReader(str(session["out"] / "candump.log")) as reader:
        frames = list(reader)
    fi = codec["FI_Command"].frame_id
    t_kill = next(m.timestamp for m in frames if m.arbitration_id == fi)
    cut = [m for m in frames if t_kill - 1.0 <= m.timestamp <= t_kill + 1.5]
    trace = tmp_path / "cut.log"
    with can.Logger(str(trace)) as writer:
        for m in cut:
            writer.on_message_received(m)
    out, rs = tmp_path / "replay.log", tmp_path / "replay.json"
    # the live ECU's TPS timeout (--tps-timeout-cycles=1000: the emulated plant's sends have
    # gaps when the host is busy), or a busy host's recording times the sensor out in replay
    assert cli_main(["replay", str(trace), "--out", str(out), "--summary", str(rs),
                     "--set", "ecu.throttle.tps_monitor.timeout_cycles=1000", "--quiet"]) == 0
    r = summary(rs)["frames"]
    inputs = {_key(codec, n) for n in ("TPS_Sensor", "ETB_Wattmeter", "ESC_Motion")}
    assert r["read"] == len(cut)
    assert r["rejected"] == 0, r["rejected_by_reason"]
    assert r["ecu_rx"]["accepted"] == sum(1 for m in cut
                                          if (m.arbitration_id, m.is_extended_id) in inputs)
    est = codec["ECU_ThrottleEstimate"]
    with can.LogReader(str(out)) as reader:
        sources = [est.decode(m.data)["THR_Source"] for m in reader
                   if m.arbitration_id == est.frame_id]
    assert len(sources) > 1000  # the 2.5 s window at 1 ms
    # the sensor before the kill (the window's first frames may still be the replayed ECU's
    # start-up), the estimate after it, and no going back once switched
    assert 0 in sources and sources[-1] == 1
    switch = len(sources) - sources[::-1].index(0)
    assert set(sources[switch:]) == {1}
