"""A conformance tester: scapy's UDS layer over its ISO-TP soft socket on python-can (scapy's
defaults; `conf.contribs['UDS']['treat-response-pending-as-answer']` stays False).
`vecu conformance run --tester "python examples/testers/scapy_uds.py"`; the contract is
examples/testers/udsoncan_isotp.py's (docs/conformance.md)."""

from __future__ import annotations

import os
import sys

from scapy.config import conf

conf.contribs["CANSocket"] = {"use-python-can": True}
conf.contribs["ISOTP"] = {"use-can-isotp-kernel-module": False}

from scapy.contrib.automotive.uds import UDS, UDS_RDBI, UDS_TP  # noqa: E402
from scapy.contrib.cansocket_python_can import PythonCANSocket  # noqa: E402
from scapy.contrib.isotp import ISOTPSoftSocket  # noqa: E402
from scapy.layers.can import CAN  # noqa: E402

P2_S = 1.0  # the answer (after any 0x78) within this per request, as a user would set


def env_id(name: str) -> int:
    return int(os.environ[name], 16)


def main() -> int:
    req, rsp, func = (env_id("VECU_UDS_REQUEST_ID"), env_id("VECU_UDS_RESPONSE_ID"),
                      env_id("VECU_UDS_FUNCTIONAL_ID"))
    can = PythonCANSocket(interface=os.environ["VECU_CAN_INTERFACE"],
                          channel=os.environ["VECU_CAN_CHANNEL"])
    ok = True
    try:
        with ISOTPSoftSocket(can, tx_id=req, rx_id=rsp, basecls=UDS, padding=True) as s:
            s.send(UDS() / UDS_TP(subFunction=0x80))  # suppressPosRsp: no answer expected
            r = s.sr1(UDS() / UDS_RDBI(identifiers=[0xF190, 0xF18C, 0xF195, 0xF186]),
                      timeout=5 * P2_S, verbose=False)
            if r is None:
                print("error: no answer to ReadDataByIdentifier")
                return 1
            print("read", bytes(r).hex())
            ok &= r.service == 0x62 and b"1VECU" in bytes(r)
            can.send(CAN(identifier=func, data=bytes([0x03, 0x22, 0xF1, 0x90, 0, 0, 0, 0])))
            answers = [p for p in s.sniff(timeout=P2_S) if p.service != 0x7F
                       or p.negativeResponseCode != 0x78]
            print("functional", [bytes(p).hex() for p in answers])
            ok &= any(bytes(p)[:3] == b"\x62\xf1\x90" for p in answers)
    except Exception as exc:  # noqa: BLE001 - a tester reports what its client raised
        print(f"error: {type(exc).__name__}: {exc}")
        ok = False
    finally:
        can.close()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
