"""vecu's bus rules on a real SocketCAN kernel, in one process: what counts as a node's own
frame, CAN FD where the interface's MTU allows it, kernel receive filters, error frames."""

from __future__ import annotations

import can

from tests.socketcan.kernel import CHANNEL, needs_kernel, tool
from vecu.bus import CANFD_MTU, open_bus, receive_filters, socketcan_mtu
from vecu.codec import DbcCodec
from vecu.live.livebus import LiveBus, sent_ids

pytestmark = needs_kernel


def test_frames_of_another_local_socket_reach_the_node_although_python_can_says_not_rx():
    """The kernel sets MSG_DONTROUTE on every frame sent on this host, and python-can turns that
    into is_rx=False: the plant's frames look like the ECU's own transmissions. LiveBus must
    take them; the node's own frames are not looped back (no receive_own_messages); a frame on
    one of the node's IDs from another socket is counted apart."""
    codec = DbcCodec()
    ecu_raw, plant = open_bus("socketcan", CHANNEL), open_bus("socketcan", CHANNEL)
    try:
        ecu = LiveBus(ecu_raw, sent_ids(codec, "VECU"), "socketcan")
        watt, est = codec["ETB_Wattmeter"], codec["ECU_ThrottleEstimate"]
        ecu.send(est.frame({"THR_CRC": 0, "THR_AliveCounter": 0, "THR_Source": 0,
                            "THR_Angle": 1.0, "THR_AngleEst": 1.0, "THR_AngleEstStd": 1.0,
                            "THR_TpsStatus": 0, "THR_Validity": 1}, 0.0))
        plant.send(watt.frame({"ETB_Voltage": 2.0, "ETB_Power": 3.0}, 0.0))
        plant.send(can.Message(arbitration_id=est.frame_id, data=bytes(8), is_extended_id=False))
        got = ecu.recv(5.0)
        assert got is not None and got.arbitration_id == watt.frame_id
        assert got.is_rx is False  # what python-can reports: the reason for the rule
        assert ecu.recv(0.5) is None
        counts = ecu.counts(codec)
        assert counts["received"] == 1 and counts["own_echo"] == 0
        assert counts["foreign_own_id"] == 1
        # the plant's socket saw the ECU's frame (kernel local loopback), not its own two
        seen = plant.recv(5.0)
        assert seen is not None and seen.arbitration_id == est.frame_id
        assert plant.recv(0.5) is None
    finally:
        ecu_raw.shutdown()
        plant.shutdown()


def test_a_vcan_with_the_fd_mtu_is_opened_for_can_fd_and_receives_fd_frames():
    assert socketcan_mtu(CHANNEL) == CANFD_MTU  # vcan's default
    bus = open_bus("socketcan", CHANNEL)
    try:
        assert bus.protocol == can.CanProtocol.CAN_FD
        tool("cansend", CHANNEL, "123##1" + "11" * 64)
        msg = bus.recv(10.0)
        assert msg is not None and msg.is_fd and msg.bitrate_switch and len(msg.data) == 64
        # classic frames still go out and come back as classic
        other = open_bus("socketcan", CHANNEL, fd=False)
        try:
            assert other.protocol == can.CanProtocol.CAN_20
            bus.send(can.Message(arbitration_id=0x321, data=b"\x01\x02", is_extended_id=False))
            got = other.recv(10.0)
            assert got is not None and not got.is_fd and bytes(got.data) == b"\x01\x02"
        finally:
            other.shutdown()
    finally:
        bus.shutdown()


def test_kernel_filters_pass_exactly_the_consumed_ids_and_error_frames():
    bus = open_bus("socketcan", CHANNEL)
    try:
        bus.set_filters(receive_filters({(0x100, False), (0x18DAF110, True)}))
        for frame in ("101#01", "100#02", "00000100#03", "18DAF110#04", "18DAF111#05",
                      "20000080#0000000000000000"):
            tool("cansend", CHANNEL, frame)
        got = [bus.recv(10.0) for _ in range(3)]
        assert bus.recv(1.0) is None
        assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got[:2]] == [
            (0x100, False, b"\x02"), (0x18DAF110, True, b"\x04")]
        assert got[2].is_error_frame  # "00000100#03" is the 29-bit ID 0x100: filtered out
    finally:
        bus.shutdown()
