from __future__ import annotations

import can
import pytest

from vecu.bus import BusOpenError, FastVirtualBus, open_bus, resolve_bus_config


def test_default_is_virtual_when_nothing_is_configured(monkeypatch, tmp_path):
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.delenv("CAN_CHANNEL", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    cfg = resolve_bus_config()
    assert cfg["interface"] == "virtual" and cfg["channel"] == "vecu"


def test_python_can_environment_config_is_honoured(monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "from-env")
    assert resolve_bus_config()["channel"] == "from-env"
    assert resolve_bus_config(channel="explicit")["channel"] == "explicit"


def test_python_can_config_file_is_honoured(tmp_path, monkeypatch):
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.delenv("CAN_CHANNEL", raising=False)
    cfg_file = tmp_path / "can.ini"
    cfg_file.write_text("[default]\ninterface = virtual\nchannel = from-file\n")
    assert resolve_bus_config(config_file=str(cfg_file))["channel"] == "from-file"


def test_unknown_interface_is_a_clear_error():
    with pytest.raises(BusOpenError, match="no-such-interface"):
        open_bus(interface="no-such-interface", channel="x")


def test_fast_virtual_bus_interoperates_with_python_can_virtual_and_isolates_receivers():
    a = open_bus(channel="iso")
    b = can.Bus(interface="virtual", channel="iso")
    c = open_bus(channel="iso")
    try:
        assert isinstance(a, FastVirtualBus)
        msg = can.Message(arbitration_id=0x123, data=[1, 2, 3], is_extended_id=False, timestamp=4.5)
        a.send(msg)
        rb, rc = b.recv(1.0), c.recv(1.0)
        assert rb is not None and rc is not None
        assert rb.equals(rc) and bytes(rb.data) == b"\x01\x02\x03"
        assert rb.timestamp == 4.5 and rb.is_rx  # sender time kept, marked as received
        rb.data[0] = 99  # a receiver mutating its frame affects nobody else
        assert rc.data[0] == 1 and msg.data[0] == 1
        assert a.recv(0.0) is None  # no echo of own frames
        b.send(can.Message(arbitration_id=0x7, data=[9]))
        got = a.recv(1.0)
        assert got is not None and got.arbitration_id == 0x7
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def _fields(m: can.Message) -> tuple:
    return (m.timestamp, m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_error_frame,
            m.channel, m.dlc, bytes(m.data), m.is_fd, m.is_rx, m.bitrate_switch,
            m.error_state_indicator, type(m.data))


def test_sim_lane_hands_frames_to_every_other_endpoint_in_order_and_copies_only_for_edges():
    from vecu.bus import SimLane

    lane = SimLane("lane-test")
    plant, ecu, log = lane.bus(), lane.bus(), lane.bus(edge=True)
    ref_tx, ref_log = open_bus(channel="lane-ref"), open_bus(channel="lane-ref")
    frames = [can.Message(timestamp=0.001 * i, arbitration_id=0x100 + i, data=bytes([i] * 4),
                          is_extended_id=False) for i in range(3)]
    frames.append(can.Message(timestamp=0.004, arbitration_id=0x1ABCDEF, is_extended_id=True,
                              is_error_frame=True))
    try:
        for m in frames:
            plant.send(m)
            ref_tx.send(m)
        ecu.send(frames[0])
        assert plant.recv(0.0) is frames[0]  # the ECU's frame; no echo of its own
        assert plant.recv(0.0) is None
        got = [ecu.recv(0.0) for _ in frames]
        assert got == frames and all(a is b for a, b in zip(got, frames))  # shared, in order
        assert ecu.recv(1.0) is None  # never waits
        logged = [log.recv(0.0) for _ in range(len(frames) + 1)]
        ref = [ref_log.recv(0.0) for _ in frames]
        # the edge's copies are what python-can's virtual bus (vecu's FastVirtualBus) delivers,
        # channel aside, and they are copies
        assert [_fields(m)[:5] + _fields(m)[6:] for m in logged[:-1]] == \
               [_fields(m)[:5] + _fields(m)[6:] for m in ref]
        assert all(m.channel == "lane-test" and m is not f for m, f in zip(logged, frames))
        assert logged[-1].is_rx is True and bytes(logged[-1].data) == bytes(frames[0].data)
        logged[0].data[0] = 0xFF  # an edge may change its copy: the frame itself stays
        assert frames[0].data[0] == 0
    finally:
        for b in (plant, ecu, log, ref_tx, ref_log):
            b.shutdown()
    assert lane.endpoints == []


def test_a_simulated_virtual_run_goes_over_the_lane_unless_a_listener_is_on_its_channel():
    """The run's nodes talk over the in-process lane (issue 16); a python-can bus of this process
    already on the run's channel (a user's listener) keeps python-can's channel and hears it all."""
    from vecu.runner import RunConfig, run

    cfg = RunConfig(duration_s=0.02, kill_tps_at_s=None, channel="lane-run")
    alone = run(cfg).summary
    assert alone["bus"] == "vecu lane"
    spy = open_bus(channel="lane-run")
    try:
        heard = run(cfg).summary
        frames = []
        while (m := spy.recv(0.0)) is not None:
            frames.append(m)
    finally:
        spy.shutdown()
    assert heard["bus"] == "FastVirtualBus"
    assert len(frames) == heard["frames"]["sent"] == alone["frames"]["sent"] > 0
    assert heard["frames"]["ecu_rx"] == alone["frames"]["ecu_rx"]


def test_receive_filters_pass_exactly_the_given_ids_with_their_id_length():
    """The same filters go to the kernel on SocketCAN (tests/socketcan); python-can applies them
    in software elsewhere."""
    from vecu.bus import receive_filters

    a, b = open_bus("virtual", "filters"), open_bus("virtual", "filters")
    try:
        b.set_filters(receive_filters({(0x100, False), (0x18DAF110, True)}))
        for can_id, ext in ((0x101, False), (0x100, False), (0x100, True), (0x18DAF110, True),
                            (0x18DAF111, True), (0x500, False)):
            a.send(can.Message(arbitration_id=can_id, is_extended_id=ext, data=b"\x01"))
        got = []
        while (m := b.recv(0.1)) is not None:
            got.append((m.arbitration_id, m.is_extended_id))
        assert got == [(0x100, False), (0x18DAF110, True)]
    finally:
        a.shutdown()
        b.shutdown()


def test_socketcan_mtu_reads_sysfs_and_says_none_for_no_such_interface():
    from vecu.bus import socketcan_mtu

    assert socketcan_mtu("no-such-can-interface") is None
    lo = socketcan_mtu("lo")  # any interface's MTU file
    assert lo is None or lo > 0
