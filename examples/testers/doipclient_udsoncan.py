"""A conformance tester for the DoIP faults: doipclient and udsoncan's DoIPClientUDSConnector
(the libraries' defaults), to the gateway at VECU_DOIP_HOST:VECU_DOIP_PORT, target
VECU_DOIP_TARGET. `vecu conformance run --doip --tester "python examples/testers/doipclient_udsoncan.py"`.
It reads the four DIDs of examples/testers/udsoncan_isotp.py; exit 0 when they came and were
right, 1 when the client reported an error (docs/conformance.md)."""

from __future__ import annotations

import os
import sys

import udsoncan
from doipclient import DoIPClient
from doipclient.connectors import DoIPClientUDSConnector
from udsoncan.client import Client


class Ascii(udsoncan.DidCodec):
    def __init__(self, size: int) -> None:
        self.size = size

    def encode(self, value: str) -> bytes:  # type: ignore[override]  # udsoncan's codec
        return value.encode("ascii")

    def decode(self, data: bytes) -> str:  # type: ignore[override]
        return bytes(data).decode("ascii", errors="replace")

    def __len__(self) -> int:
        return self.size


def main() -> int:
    config = {**udsoncan.configs.default_client_config,
              "data_identifiers": {0xF190: Ascii(17), 0xF18C: Ascii(10), 0xF195: Ascii(15),
                                   0xF186: Ascii(1)}}
    try:
        doip = DoIPClient(os.environ["VECU_DOIP_HOST"], int(os.environ["VECU_DOIP_TARGET"], 16),
                          tcp_port=int(os.environ["VECU_DOIP_PORT"]),
                          client_logical_address=0x0E00)
        with Client(DoIPClientUDSConnector(doip), config=config) as client:
            values = client.read_data_by_identifier([0xF190, 0xF18C, 0xF195, 0xF186]).service_data.values
            print("read", {hex(k): v for k, v in values.items()})
            ok = values[0xF190].startswith("1VECU")
        doip.close()
    except Exception as exc:  # noqa: BLE001 - a tester reports what its client raised
        print(f"error: {type(exc).__name__}: {exc}")
        return 1
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
