"""The catalogue of named diagnostic faults: one `DiagFault` record each, in `FAULTS`.

A record holds every fact of its fault: the layer it acts on (UDS response path, ISO-TP frames,
DoIP at the gateway), its one parameter with bounds, what the ECU or gateway then does, the
client behaviour the standard asks and the clause or timing parameter that asks it, and how the
bench judges a tester: its exit status (`outcome`) and a rule on the frames it sent (`rule`).

Timing parameters (defaults of vecu's ECU, docs/uds.md): P2server 50 ms, P2*server 5000 ms
(ISO 14229-2 §7.2); N_Bs = N_Cr = 1000 ms, N_WFTmax 10 (ISO 15765-2:2016 §9.7, §9.6.5.4);
A_DoIP_Diagnostic_Message 2 s (ISO 13400-2 timing parameters).

Each fault switched on or off is an FI_Event frame (dbc/vecu.dbc) with FI_EvKind 31
("diag"): FI_EvSignal carries the record's `code`, FI_EvMessageId the CAN ID (or DoIP logical
address) it acts on, FI_EvValue its parameter. FI_EvKind's codes 0-29 stay with the signal /
frame faults and the restbus disturbances; the diagnostic faults get their own 8-bit code space
under that one kind instead of taking the last free 5-bit codes.
"""

from __future__ import annotations

from dataclasses import dataclass

from vecu.errors import BadArgumentError

DIAG_EV_KIND = 31  # FI_EvKind of a diagnostic fault's FI_Event frame
P2_MS, P2_STAR_MS = 50.0, 5000.0  # vecu's P2server / P2*server defaults (ecu.uds.*)
N_BS_MS = N_CR_MS = 1000.0        # ISO 15765-2 N_Bs / N_Cr timeouts
N_WFTMAX = 10                     # WAIT frames a receiver sends at most (a common default)
PENDING_INTERVAL_MS = 200.0       # between two 0x78 (well inside P2*server)
WAIT_INTERVAL_MS = 200.0          # between two FC WAIT (inside N_Bs)
STMIN_ALLOWED = (0x7F, *range(0x80, 0xF1), *range(0xFA, 0x100))  # 0x7F and the reserved values

ANSWER, ERROR, EITHER = "answer", "error", "either"  # the tester's exit status: 0, 1, 0 or 1


@dataclass(frozen=True)
class DiagFault:
    name: str
    code: int          # FI_EvSignal of its FI_Event frame
    layer: str         # "uds", "isotp-rx" (the ECU receives), "isotp-tx" (the ECU sends), "doip"
    does: str          # what the ECU / gateway does
    expect: str        # what the client must do
    clause: str        # the standard's clause or timing parameter
    outcome: str = ANSWER  # tester exit status: answer 0, error 1 (reported, not hung), either
    rule: str = ""     # bus rule the bench checks (vecu.conformance.judge.RULES)
    param: str = ""    # meaning of VALUE ("": none)
    default: float = 0.0
    lo: float = 0.0
    hi: float = 0.0
    allowed: tuple[int, ...] = ()  # the only values allowed (besides lo..hi when both set)

    def checked(self, value: float | None) -> float:
        """The value to use (the default for None); BadArgumentError outside the bounds."""
        if value is None:
            return self.default
        if not self.param:
            raise BadArgumentError(f"diagnostic fault {self.name} takes no value, got {value:g}")
        ok = (value in self.allowed) if self.allowed else self.lo <= value <= self.hi
        if not ok or value != int(value):
            raise BadArgumentError(f"diagnostic fault {self.name}: {self.param} must be "
                                   f"{self.range_text()}, got {value:g}")
        return float(value)

    def range_text(self) -> str:
        if self.allowed:
            return "0x7F, 0x80..0xF0 or 0xFA..0xFF"
        return f"an integer {self.lo:g}..{self.hi:g}" if self.param else "no value"

    @property
    def doip(self) -> bool:
        return self.layer == "doip"

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "code": self.code, "layer": self.layer, "does": self.does,
                "expect": self.expect, "clause": self.clause, "outcome": self.outcome,
                "rule": self.rule, "param": self.param or None,
                "default": self.default if self.param else None,
                "range": self.range_text() if self.param else None}


def _f(*args: object, **kw: object) -> DiagFault:
    return DiagFault(*args, **kw)  # type: ignore[arg-type]


_T14229 = "ISO 14229-2 §7.2 (P2/P2* client timing), ISO 14229-1 §10.3.6 NRC 0x78"
_RECORDS = (
    # ------------------------------------------------------------------ UDS (response path)
    _f("pending", 1, "uds", "NRC 0x78 (requestCorrectlyReceived-ResponsePending) N times, one "
       "every 200 ms, then the answer", "wait on: each 0x78 restarts P2*client; take the final "
       "answer; never take 0x78 as the answer, never resend the request while pending", _T14229,
       ANSWER, "no_request_while_pending", "N", 1, 1, 100),
    _f("pending_forever", 2, "uds", "NRC 0x78 every 200 ms, never an answer",
       "never take 0x78 as the answer; give up by the client's own limit and report it",
       _T14229, ERROR),
    _f("late_p2", 3, "uds", "the answer VALUE ms after the request, beyond P2client",
       "time out at P2client (P2server_max 50 ms + network margin) and report it",
       "ISO 14229-2 §7.2 P2client", ERROR, "", "ms", 1100, 51, 60000),
    _f("early_p2", 4, "uds", "the answer VALUE ms after the request, just before P2server_max",
       "take the answer", "ISO 14229-2 §7.2 P2server_max", ANSWER, "", "ms", 45, 0, 50),
    _f("late_p2star", 5, "uds", "one NRC 0x78, then the answer VALUE ms after it, beyond "
       "P2*client", "time out at P2*client (P2*server_max 5000 ms + margin) and report it",
       "ISO 14229-2 §7.2 P2*client", ERROR, "", "ms", 6500, 5001, 120000),
    _f("no_response", 6, "uds", "no answer at all", "time out at P2client and report it; no hang",
       "ISO 14229-2 §7.2 P2client", ERROR),
    _f("busy_repeat", 7, "uds", "NRC 0x21 (busyRepeatRequest) to the first N requests, then the "
       "answer", "repeat the request later, or report the NRC; never hang",
       "ISO 14229-1 §10.3.6 / Annex A NRC 0x21", EITHER, "", "N", 1, 1, 100),
    _f("wrong_sid", 8, "uds", "a positive response whose SID is not request SID + 0x40",
       "reject it: it does not answer the request", "ISO 14229-1 §8.7 (response SID)", ERROR),
    _f("truncated", 9, "uds", "the positive response cut short by VALUE bytes",
       "reject it (wrong length), do not decode garbage", "ISO 14229-1 §8.7, §10.3.6 NRC 0x13",
       ERROR, "", "bytes", 1, 1, 16),
    _f("overlong", 10, "uds", "VALUE extra bytes after the positive response",
       "reject it or ignore the excess; never misread the data", "ISO 14229-1 §8.7",
       EITHER, "", "bytes", 1, 1, 64),
    _f("spr_answered", 11, "uds", "a positive response although suppressPosRspMsgIndicationBit "
       "was set", "ignore it: not an answer to the next request",
       "ISO 14229-1 §8.5.2 (suppressPosRspMsgIndicationBit)", ANSWER),
    _f("unsolicited", 12, "uds", "an unsolicited single frame on the response ID VALUE ms after "
       "each answer (between requests)", "ignore it: not an answer to the next request",
       "ISO 14229-2 §7.2 (a response only to a request)", ANSWER, "", "ms", 20, 1, 1000),
    _f("functional_multi", 13, "uds", "VALUE more ECUs (response ID + 1..VALUE) answer each "
       "functional request at once, each a segmented response",
       "collect every response until P2client; send a flow control to each responder",
       "ISO 14229-2 §7.3 (functional communication), ISO 15765-2 §9.6.5", ANSWER,
       "fc_to_each_responder", "ECUs", 1, 1, 7),
    _f("functional_staggered", 14, "uds", "one more ECU answers each functional request VALUE ms "
       "after the ECU, a segmented response", "collect both; flow control to each responder",
       "ISO 14229-2 §7.3, ISO 15765-2 §9.6.5", ANSWER, "fc_to_each_responder", "ms", 30, 1, 49),
    # ------------------------------------------------- ISO-TP, the ECU receives a request
    _f("fc_wait", 15, "isotp-rx", "flow control WAIT VALUE times (every 200 ms), then CTS",
       "restart N_Bs on each WAIT; no consecutive frame before the CTS; complete the request",
       "ISO 15765-2:2016 §9.6.5.1 FS=WAIT, N_Bs", ANSWER, "cf_only_after_cts", "WAITs", 3, 1,
       N_WFTMAX),
    _f("fc_wait_excess", 16, "isotp-rx", "flow control WAIT VALUE times, beyond N_WFTmax, then "
       "CTS", "no consecutive frame before the CTS; wait on or abort, never loop forever",
       "ISO 15765-2:2016 §9.6.5.1, N_WFTmax", EITHER, "cf_only_after_cts", "WAITs", 20,
       N_WFTMAX + 1, 100),
    _f("fc_overflow", 17, "isotp-rx", "flow control FS=OVFLW to the first frame",
       "abort the transmission (N_BUFFER_OVFLW): no consecutive frame",
       "ISO 15765-2:2016 §9.6.5.1 FS=OVFLW", ERROR, "cf_only_after_cts"),
    _f("fc_invalid_fs", 18, "isotp-rx", "flow control with the invalid flow status VALUE",
       "abort the transmission (N_INVALID_FS): no consecutive frame",
       "ISO 15765-2:2016 §9.6.5.1, §9.8.3", ERROR, "cf_only_after_cts", "FS", 3, 3, 15),
    _f("fc_stmin", 19, "isotp-rx", "flow control CTS with STmin VALUE (0x7F or reserved)",
       "reserved STmin: use the longest, 127 ms; never abort; consecutive frames >= 127 ms apart",
       "ISO 15765-2:2016 §9.6.5.5 (STmin)", ANSWER, "cf_gap_127ms", "STmin", 0xFA,
       allowed=STMIN_ALLOWED),
    _f("fc_blocksize", 20, "isotp-rx", "flow control CTS with BS VALUE (a new FC after each "
       "block)", "send at most BS consecutive frames, then wait for the next flow control",
       "ISO 15765-2:2016 §9.6.5.3 (BlockSize)", ANSWER, "cf_per_block", "BS", 1, 1, 15),
    _f("fc_late", 21, "isotp-rx", "the flow control VALUE ms after the first frame, beyond N_Bs",
       "time out at N_Bs (1000 ms) and abort: no consecutive frame after the late FC",
       "ISO 15765-2:2016 §9.7 N_Bs", ERROR, "cf_only_after_cts", "ms", 1500, 1001, 60000),
    _f("fc_never", 22, "isotp-rx", "no flow control to the first frame",
       "time out at N_Bs and report it; no hang", "ISO 15765-2:2016 §9.7 N_Bs", ERROR,
       "cf_only_after_cts"),
    # -------------------------------------------------- ISO-TP, the ECU sends a response
    _f("cf_wrong_sn", 23, "isotp-tx", "the second consecutive frame's sequence number off by "
       "VALUE", "abort the reception (N_WRONG_SN), report it", "ISO 15765-2:2016 §9.6.4.3, "
       "§9.8.3", ERROR, "", "offset", 1, 1, 14),
    _f("cf_repeated_sn", 24, "isotp-tx", "the first consecutive frame sent twice (a repeated "
       "sequence number)", "abort the reception (N_WRONG_SN), report it",
       "ISO 15765-2:2016 §9.6.4.3", ERROR),
    _f("cf_missing", 25, "isotp-tx", "the consecutive frames stop after VALUE of them",
       "time out at N_Cr (1000 ms), report it; no hang", "ISO 15765-2:2016 §9.7 N_Cr", ERROR,
       "", "CFs", 0, 0, 2),
    _f("ff_bad_length", 26, "isotp-tx", "a first frame with FF_DL = VALUE (below 8: invalid on "
       "classical CAN)", "ignore the first frame: no flow control", "ISO 15765-2:2016 §9.6.3.2",
       ERROR, "no_fc_after_fault", "FF_DL", 7, 0, 7),
    _f("ff_escape32", 27, "isotp-tx", "the response's first frame in the 32-bit FF_DL escape "
       "form (FF_DL 0 + 4 bytes) although under 4096 bytes",
       "take it (2016 edition) or ignore the first frame; never misread or hang",
       "ISO 15765-2:2016 §9.6.3.1 (FF_DL > 4095 escape)", EITHER),
    _f("sf_during_rx", 28, "isotp-tx", "a single frame (NRC 0x10) on the response ID in the "
       "middle of the segmented response", "abort the reception and take the single frame as a "
       "new message", "ISO 15765-2:2016 §9.8.3 (unexpected N_PDU)", ERROR),
    _f("ff_during_rx", 29, "isotp-tx", "the segmented response restarted with a new first frame "
       "after its first consecutive frame", "abort the first reception, take the new one: a "
       "flow control to the second first frame", "ISO 15765-2:2016 §9.8.3", ANSWER,
       "fc_after_second_ff"),
    _f("no_padding", 30, "isotp-tx", "response frames without padding (CAN DLC = bytes used)",
       "accept them", "ISO 15765-2:2016 §10.4.2 (CAN frame data optimisation)", ANSWER),
    _f("padding_byte", 31, "isotp-tx", "response frames padded with VALUE instead of 0xCC",
       "ignore the padding bytes' value", "ISO 15765-2:2016 §10.4.2.1", ANSWER, "", "byte",
       0x55, 0, 255),
    _f("canfd_frame", 32, "isotp-tx", "the response as one CAN FD single frame (FDF, escape "
       "SF_DL) to a classical CAN tester", "ignore the CAN FD frame (not its frame format): "
       "no answer, report a timeout", "ISO 15765-2:2016 §10.4 (CAN_DL), ISO 11898-1 FDF",
       ERROR),
    # ---------------------------------------------------------- DoIP, at the gateway
    _f("doip_activation_refused", 33, "doip", "routing activation response code VALUE "
       "(a refusal)", "report the refusal; send no diagnostic message on the socket",
       "ISO 13400-2:2019 §7.7.4 (routing activation response codes)", ERROR, "", "code", 0,
       0, 7),
    _f("doip_diag_nack", 34, "doip", "diagnostic message negative acknowledgement (0x8003) with "
       "code VALUE", "report the NACK; do not wait for a response",
       "ISO 13400-2:2019 §7.8.4 (diagnostic message NACK codes)", ERROR, "", "code", 3, 2, 8),
    _f("doip_ack_late", 35, "doip", "the diagnostic message ACK (0x8002) VALUE ms late, beyond "
       "A_DoIP_Diagnostic_Message", "time out and report it", "ISO 13400-2:2019 "
       "A_DoIP_Diagnostic_Message (2 s)", ERROR, "", "ms", 2500, 2001, 60000),
    _f("doip_ack_no_response", 36, "doip", "the ACK, then no diagnostic response",
       "time out at P2client and report it", "ISO 13400-2:2019 §7.8, ISO 14229-2 P2client",
       ERROR),
    _f("doip_alive_check", 37, "doip", "an alive check request (0x0007) to the tester before "
       "the diagnostic response", "answer with an alive check response (0x0008) with its "
       "source address; take the diagnostic response", "ISO 13400-2:2019 §7.6 (alive check)",
       ANSWER, "alive_check_answered"),
    _f("doip_close_mid_response", 38, "doip", "the TCP connection closed after the ACK, before "
       "the response", "report the lost connection; no hang", "ISO 13400-2:2019 §7.3 (TCP "
       "socket handling)", ERROR),
    _f("doip_header_nack", 39, "doip", "a generic DoIP header NACK (0x0000) with code VALUE "
       "instead of the ACK", "report it; no hang", "ISO 13400-2:2019 §7.1.2 (generic header "
       "NACK codes)", ERROR, "", "code", 0, 0, 4),
    _f("doip_bad_inverse_version", 40, "doip", "every message to the tester (from the routing activation response on) with an inverse "
       "protocol version that does not match the version", "discard those messages (header "
       "check): no answer, report it", "ISO 13400-2:2019 §7.1.2 (generic header check)", ERROR),
)
FAULTS: dict[str, DiagFault] = {f.name: f for f in _RECORDS}
BY_CODE: dict[int, DiagFault] = {f.code: f for f in _RECORDS}


def fault(name: str) -> DiagFault:
    """The record named `name`; BadArgumentError naming the known ones."""
    rec = FAULTS.get(name.strip().lower().replace("-", "_"))
    if rec is None:
        raise BadArgumentError(f"unknown diagnostic fault {name!r} (known: "
                               f"{', '.join(FAULTS)})")
    return rec
