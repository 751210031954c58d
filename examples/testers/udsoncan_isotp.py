"""A conformance tester: udsoncan over can-isotp on python-can, configured as a new user would
(the libraries' defaults). `vecu conformance run --tester "python examples/testers/udsoncan_isotp.py"`.

The bench's contract (docs/conformance.md): the bus and IDs come from VECU_* environment
variables; it sends TesterPresent with suppressPosRsp, one ReadDataByIdentifier of four DIDs
(a segmented request and response), then a functional ReadDataByIdentifier 0xF190; exit 0 when
every answer came and was right, 1 when the client reported an error."""

from __future__ import annotations

import os
import sys

import can
import isotp
import udsoncan
from udsoncan.client import Client
from udsoncan.connections import PythonIsoTpConnection

DIDS = (0xF190, 0xF18C, 0xF195, 0xF186)


class Ascii(udsoncan.DidCodec):
    def __init__(self, size: int) -> None:
        self.size = size

    def encode(self, value: str) -> bytes:  # type: ignore[override]  # udsoncan's codec
        return value.encode("ascii")

    def decode(self, data: bytes) -> str:  # type: ignore[override]
        return bytes(data).decode("ascii", errors="replace")

    def __len__(self) -> int:
        return self.size


def env_id(name: str) -> int:
    return int(os.environ[name], 16)


def main() -> int:
    bus = can.Bus(interface=os.environ["VECU_CAN_INTERFACE"], channel=os.environ["VECU_CAN_CHANNEL"])
    req, rsp, func = (env_id("VECU_UDS_REQUEST_ID"), env_id("VECU_UDS_RESPONSE_ID"),
                      env_id("VECU_UDS_FUNCTIONAL_ID"))
    config = {**udsoncan.configs.default_client_config,
              "data_identifiers": {0xF190: Ascii(17), 0xF18C: Ascii(10), 0xF195: Ascii(15),
                                   0xF186: Ascii(1)}}
    ok = True
    try:
        notifier = can.Notifier(bus, [])
        stack = isotp.NotifierBasedCanStack(bus, notifier, address=isotp.Address(
            isotp.AddressingMode.Normal_11bits, txid=req, rxid=rsp))
        # the functional request goes out on its own ID; the answer (and its flow control)
        # is the physical channel's, as ISO 15765-2 has it
        mode = isotp.AddressingMode.Normal_11bits
        functional = isotp.NotifierBasedCanStack(bus, notifier, address=isotp.AsymmetricAddress(
            tx_addr=isotp.Address(mode, txid=func, tx_only=True),
            rx_addr=isotp.Address(mode, rxid=func, rx_only=True)))  # receives nothing
        functional.start()
        conn = PythonIsoTpConnection(stack)
        with Client(conn, config=config) as client:
            with client.suppress_positive_response(wait_nrc=False):
                client.tester_present()
            values = client.read_data_by_identifier(list(DIDS)).service_data.values
            print("read", {hex(k): v for k, v in values.items()})
            ok &= values[0xF190].startswith("1VECU")
            conn.empty_rxqueue()
            functional.send(bytes([0x22, 0xF1, 0x90]))
            answer, timeout = None, config["p2_timeout"]
            while answer is None:
                payload = conn.wait_frame(timeout=timeout, exception=True)
                response = udsoncan.Response.from_payload(payload)
                if response.code == udsoncan.Response.Code.RequestCorrectlyReceived_ResponsePending:
                    timeout = config["p2_star_timeout"]
                    continue
                answer = payload
            print("functional", answer.hex())
            ok &= answer[:3] == b"\x62\xf1\x90"
        functional.stop()
        notifier.stop()
    except Exception as exc:  # noqa: BLE001 - a tester reports what its client raised
        print(f"error: {type(exc).__name__}: {exc}")
        ok = False
    finally:
        bus.shutdown()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
