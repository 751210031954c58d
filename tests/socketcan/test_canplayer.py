"""A vecu recording played by can-utils' canplayer into a live `vecu ecu` on vcan0 (the channel
mapping `vcan0=vecu`: vecu's logs name the channel `vecu`). The ECU runs with --rx-filter, so the
kernel passes it only what it consumes: the recording's truth frames and the recorded ECU's own
broadcast never reach it."""

from __future__ import annotations

from collections import Counter

import can

from tests.socketcan.kernel import (
    CHANNEL,
    START_S,
    Processes,
    ecu_drained,
    needs_kernel,
    summary,
    tool,
)
from vecu.cli import main as cli_main
from vecu.codec import DbcCodec

pytestmark = needs_kernel


def test_canplayer_replays_a_vecu_recording_into_the_live_ecu(tmp_path):
    rec = tmp_path / "drive.log"
    assert cli_main(["run", "--duration", "3", "--seed", "4", "--log", str(rec), "--quiet"]) == 0
    with can.LogReader(str(rec)) as reader:
        frames = list(reader)
    assert {m.channel for m in frames} == {"vecu"}
    in_file = Counter((m.arbitration_id, m.is_extended_id) for m in frames)
    procs = Processes(tmp_path)
    try:
        procs.vecu("ecu", "ecu", "--interface", "socketcan", "--channel", CHANNEL, "--no-status",
                   "--quiet", "--rx-filter", "--summary", str(tmp_path / "ecu.json"),
                   "--ready-file", str(tmp_path / "ecu.ready"), "--sync-timeout", str(START_S),
                   "--duration", "1800", "--tps-timeout-cycles=1000", "--host-gap-ms=5000",
                   "--rx-buffer-mb", "256")
        procs.ready("ecu", tmp_path / "ecu.ready")
        tool("canplayer", "-I", str(rec), f"{CHANNEL}=vecu", timeout_s=300)
        assert ecu_drained() == bytes([0x7E, 0x00])  # every frame played is taken
        assert procs.stop("ecu") == 0, procs.stderr("ecu")
    finally:
        procs.close()
    ecu = summary(tmp_path / "ecu.json")
    codec = DbcCodec()
    consumed = {codec[n].frame_id for n in ("TPS_Sensor", "ETB_Wattmeter", "ESC_Motion",
                                            "CHS_Lateral", "SWA_Sensor", "ENG_Event",
                                            "ENG_Intake")}
    assert ecu["bus"]["rx_filter"] is not None
    assert {int(i, 16) for i in ecu["bus"]["rx_filter"]} >= consumed
    taken = ecu["bus"]["rx_by_id"]
    for fid in consumed:  # every frame canplayer sent on a consumed ID reached the ECU
        name = codec.by_id[(fid, False)].name
        assert taken.get(name) == in_file[(fid, False)], name
    # nothing else: no truth frames, no recorded ECU frames on the ECU's own IDs; 0x7E0: the
    # drain check's TesterPresent
    assert set(taken) == {codec.by_id[(fid, False)].name for fid in consumed} | {"0x7E0"}
    assert taken["0x7E0"] == 1
    assert ecu["bus"]["foreign_own_id"] == 0 and ecu["rx"]["unknown_id"] == 0
    assert ecu["rx"]["rejected"] == 0 and ecu["rx"]["ignored"] == 0
    th = ecu["throttle"]
    assert th["detected_as"] == "range_low" and th["final_source"] == "estimate", th
