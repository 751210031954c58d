from __future__ import annotations

import socket

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


def _vcan_available() -> bool:
    if not hasattr(socket, "AF_CAN"):
        return False
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        s.bind(("vcan0",))
        s.close()
        return True
    except OSError:
        return False


@pytest.mark.skipif(not _vcan_available(), reason="no SocketCAN vcan0 on this machine")
def test_socketcan_vcan_roundtrip():
    a = open_bus(interface="socketcan", channel="vcan0")
    b = open_bus(interface="socketcan", channel="vcan0")
    try:
        a.send(can.Message(arbitration_id=0x321, data=[1, 2], is_extended_id=False))
        got = b.recv(1.0)
        assert got is not None and got.arbitration_id == 0x321
    finally:
        a.shutdown()
        b.shutdown()
