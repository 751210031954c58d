"""The UDS server's parameters (`ecu.uds.*` in the parameter tree; docs/uds.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

from vecu.instances import uds_ids

CAN_ID_BOUNDS = {"bounds": (0, 0x7FF)}


@dataclass(frozen=True)
class UdsConfig:
    enabled: bool = True  # False: the ECU claims no diagnostic ID (a 0x7E0 frame is unknown)
    # instance 0's IDs (vecu.instances: ecu.instance moves them unless they are set)
    request_id: int = field(default=uds_ids(0)["request_id"], metadata=CAN_ID_BOUNDS)  # physical
    response_id: int = field(default=uds_ids(0)["response_id"], metadata=CAN_ID_BOUNDS)  # all
    functional_id: int = field(default=uds_ids(0)["functional_id"],
                               metadata=CAN_ID_BOUNDS)  # functional requests
    p2_ms: float = field(default=50.0, metadata={"bounds": (1.0, 65535.0)})
    p2_star_ms: float = field(default=5000.0, metadata={"bounds": (10.0, 655350.0)})
    s3_ms: float = field(default=5000.0, metadata={"bounds": (100.0, 600000.0)})
    security_attempts: int = field(default=3, metadata={"bounds": (1, 255)})
    security_delay_ms: float = field(default=10000.0, metadata={"bounds": (0.0, 3600000.0)})
    max_dids_per_request: int = field(default=16, metadata={"bounds": (1, 64)})
    # bounded work per 1 ms tick: CAN frames taken in, requests answered, frames sent
    frames_per_tick: int = field(default=32, metadata={"bounds": (1, 1024)})
    requests_per_tick: int = field(default=4, metadata={"bounds": (1, 64)})
    request_queue: int = field(default=8, metadata={"bounds": (1, 1024)})
    vin: str = "1VECU00SIM0000001"
    serial: str = "VECU-00001"


@dataclass(frozen=True)
class UdsStep:
    """A scenario's UDS request at `at_s` and what its response must be (docs/scenarios.md)."""

    at_s: float
    request: bytes
    functional: bool = False
    key: bool = False                  # append the key for the last seed the tester received
    expect: bytes | None = None        # the response starts with these bytes
    expect_nrc: int | None = None      # a negative response with this code
    expect_contains: bytes | None = None  # these bytes appear in the response
    expect_absent: bytes | None = None    # these bytes do not appear after the response's
                                          # first 3 bytes (e.g. a DTC that must be gone)
    expect_none: bool = False          # no response at all (suppressed positive response)

    def judge(self, response: bytes | None) -> tuple[bool, str, str]:
        """(passed, what came, what was expected)."""
        got = "no response" if response is None else response.hex(" ")
        wants, ok = [], True
        if self.expect_none:
            wants.append("no response")
            ok &= response is None
        elif response is None:
            return False, got, "a response"
        else:
            if self.expect is not None:
                wants.append(f"starts {self.expect.hex(' ')}")
                ok &= response.startswith(self.expect)
            if self.expect_nrc is not None:
                wants.append(f"NRC 0x{self.expect_nrc:02X}")
                ok &= response[:1] == b"\x7f" and response[2:3] == bytes([self.expect_nrc])
            if self.expect_contains is not None:
                wants.append(f"contains {self.expect_contains.hex(' ')}")
                ok &= self.expect_contains in response
            if self.expect_absent is not None:
                wants.append(f"lacks {self.expect_absent.hex(' ')}")
                ok &= self.expect_absent not in response[3:]
            if not wants:
                wants.append("a positive response")
                ok &= response[:1] != b"\x7f"
        return ok, got, ", ".join(wants)
