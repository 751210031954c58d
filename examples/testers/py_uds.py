"""A conformance tester: py-uds (mdabrowski1990/uds, `pip install py-uds`) with its python-can
transport interface and its Client's default timing. `vecu conformance run --tester "python
examples/testers/py_uds.py"`; the contract is examples/testers/udsoncan_isotp.py's
(docs/conformance.md). A functional request in py-uds goes out on the functional CAN ID and its
flow control on the physical one, as ISO 15765-2 has it."""

from __future__ import annotations

import os
import sys

import can
from uds.addressing import AddressingType
from uds.can.addressing import CanAddressingFormat, CanAddressingInformation
from uds.can.transport_interface.python_can import PyCanTransportInterface
from uds.client import Client
from uds.message import UdsMessage


def env_id(name: str) -> int:
    return int(os.environ[name], 16)


def main() -> int:
    req, rsp, func = (env_id("VECU_UDS_REQUEST_ID"), env_id("VECU_UDS_RESPONSE_ID"),
                      env_id("VECU_UDS_FUNCTIONAL_ID"))
    bus = can.Bus(interface=os.environ["VECU_CAN_INTERFACE"], channel=os.environ["VECU_CAN_CHANNEL"])
    ok = True
    try:
        ai = CanAddressingInformation(
            addressing_format=CanAddressingFormat.NORMAL_ADDRESSING,
            rx_physical_params={"can_id": rsp}, tx_physical_params={"can_id": req},
            rx_functional_params={"can_id": rsp}, tx_functional_params={"can_id": func})
        client = Client(PyCanTransportInterface(bus, ai))
        client.send_request_receive_responses(UdsMessage([0x3E, 0x80], AddressingType.PHYSICAL))
        _, responses = client.send_request_receive_responses(UdsMessage(
            [0x22, 0xF1, 0x90, 0xF1, 0x8C, 0xF1, 0x95, 0xF1, 0x86], AddressingType.PHYSICAL))
        final = bytes(responses[-1].payload) if responses else b""
        print("read", final.hex())
        ok &= final[:1] == b"\x62" and b"1VECU" in final and len(final) == 52
        _, responses = client.send_request_receive_responses(UdsMessage(
            [0x22, 0xF1, 0x90], AddressingType.FUNCTIONAL))
        answers = [bytes(r.payload) for r in responses]
        print("functional", [a.hex() for a in answers])
        ok &= any(a[:3] == b"\x62\xf1\x90" for a in answers)
    except Exception as exc:  # noqa: BLE001 - a tester reports what its client raised
        print(f"error: {type(exc).__name__}: {exc}")
        ok = False
    finally:
        bus.shutdown()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
