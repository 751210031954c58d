"""How the bench judges a tester: its exit status against the fault's `outcome`, and the
fault's `rule` on the frames it sent (RULES: one function per rule name of the catalogue).
Frames are (t_s, can.Message) as the bench captured them; each rule returns (kept, evidence)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import can

from vecu.uds.diag_faults.catalogue import ANSWER, ERROR, N_BS_MS, DiagFault

Frames = list[tuple[float, can.Message]]
NBS_S = N_BS_MS / 1000 + 0.1  # N_Bs with a margin for a loaded host


@dataclass(frozen=True)
class Ids:
    request: int
    response: int
    functional: int


def _pci(msg: can.Message) -> int:
    return msg.data[0] >> 4 if len(msg.data) else -1


def _on(frames: Frames, can_id: int) -> Frames:
    return [(t, m) for t, m in frames if m.arbitration_id == can_id]


def _ms(t: float, t0: float) -> str:
    return f"{(t - t0) * 1000:.0f} ms"


def cf_only_after_cts(frames: Frames, ids: Ids, value: float, extra: dict) -> tuple[bool, str]:
    """ISO 15765-2 §9.6.5.1: a consecutive frame only after a CTS from the receiver that came
    within N_Bs of the first frame or the last WAIT; never after OVFLW or an invalid FS."""
    t0 = frames[0][0] if frames else 0.0
    state, since = "idle", 0.0  # idle / wait_fc (after FF or WAIT) / go (after a timely CTS) / stop
    for t, m in sorted(frames, key=lambda f: f[0]):
        pci = _pci(m)
        if m.arbitration_id == ids.request and pci == 1:
            state, since = "wait_fc", t
        elif m.arbitration_id == ids.response and pci == 3 and state in ("wait_fc", "go"):
            fs = m.data[0] & 0x0F
            if fs == 1 and state == "wait_fc":
                since = t
            elif fs == 0:
                state = "go" if state == "go" or t - since <= NBS_S else "stop"
            else:
                state = "stop"
        elif m.arbitration_id == ids.request and pci == 2 and state != "go":
            return False, f"consecutive frame at {_ms(t, t0)} without a timely CTS ({state})"
    return True, "no consecutive frame without a timely CTS"


def cf_gap_127ms(frames: Frames, ids: Ids, value: float, extra: dict) -> tuple[bool, str]:
    """§9.6.5.5: STmin 0x7F or reserved: at least 127 ms between consecutive frames."""
    cfs = [t for t, m in _on(frames, ids.request) if _pci(m) == 2]
    gaps = [b - a for a, b in zip(cfs, cfs[1:])]
    if not cfs:
        return False, "no consecutive frame sent (aborted on the STmin value)"
    short = [g for g in gaps if g < 0.125]
    return (not short, f"{len(cfs)} consecutive frames, smallest gap "
            f"{min(gaps) * 1000:.0f} ms" if gaps else "1 consecutive frame")


def cf_per_block(frames: Frames, ids: Ids, value: float, extra: dict) -> tuple[bool, str]:
    """§9.6.5.3: at most BS consecutive frames, then wait for the next flow control."""
    run, worst = 0, 0
    for _, m in sorted(frames, key=lambda f: f[0]):
        if m.arbitration_id == ids.response and _pci(m) == 3:
            run = 0
        elif m.arbitration_id == ids.request and _pci(m) == 2:
            run += 1
            worst = max(worst, run)
    return worst <= value, f"at most {worst} consecutive frames per block (BS {value:g})"


def fc_to_each_responder(frames: Frames, ids: Ids, value: float,
                         extra: dict) -> tuple[bool, str]:
    """ISO 14229-2 §7.3 / 15765-2: a flow control to every responder's first frame."""
    missing, seen = [], 0
    for k in range(8):
        ffs = [t for t, m in _on(frames, ids.response + k) if _pci(m) == 1]
        if not ffs:
            continue
        seen += 1
        if not any(_pci(m) == 3 and t >= ffs[0] for t, m in _on(frames, ids.request + k)):
            missing.append(f"0x{ids.response + k:X}")
    return not missing and seen > 1, (f"{seen} responders, no flow control to {missing}"
                                      if missing else f"flow control to all {seen} responders")


def no_fc_after_fault(frames: Frames, ids: Ids, value: float, extra: dict) -> tuple[bool, str]:
    """§9.6.3.2: a first frame with an invalid FF_DL is ignored: no flow control to it."""
    bad = [t for t, m in _on(frames, ids.response) if _pci(m) == 1 and m.data[1] < 8
           and m.data[0] & 0x0F == 0]
    fcs = [t for t, m in _on(frames, ids.request) if _pci(m) == 3 and bad and t >= bad[0]]
    return not fcs, (f"flow control {_ms(fcs[0], bad[0])} after the invalid first frame"
                     if fcs else "no flow control to the invalid first frame")


def fc_after_second_ff(frames: Frames, ids: Ids, value: float, extra: dict) -> tuple[bool, str]:
    """§9.8.3: a new first frame during a reception starts a new one: a flow control to it."""
    ffs = [t for t, m in _on(frames, ids.response) if _pci(m) == 1]
    if len(ffs) < 2:
        return False, "the second first frame was not sent (no request?)"
    fcs = [t for t, m in _on(frames, ids.request) if _pci(m) == 3 and t >= ffs[1]]
    return bool(fcs), ("flow control to the second first frame" if fcs
                       else "no flow control to the second first frame")


def no_request_while_pending(frames: Frames, ids: Ids, value: float,
                             extra: dict) -> tuple[bool, str]:
    """ISO 14229-2 §7.2: after 0x78 the client waits; it does not send the request again."""
    rsp = _on(frames, ids.response)
    pend = [t for t, m in rsp if _pci(m) == 0 and bytes(m.data[1:2]) == b"\x7f"
            and len(m.data) > 3 and m.data[3] == 0x78]
    if not pend:
        return False, "no 0x78 was sent (no request?)"
    final = [t for t, m in rsp if t > pend[-1] and _pci(m) in (0, 1)]
    end = final[0] if final else float("inf")
    again = [t for t, m in _on(frames, ids.request) if _pci(m) in (0, 1) and pend[0] < t < end]
    return not again, (f"request sent again {_ms(again[0], pend[0])} after the first 0x78"
                       if again else f"no new request during {len(pend)} x 0x78")


def alive_check_answered(frames: Frames, ids: Ids, value: float,
                         extra: dict) -> tuple[bool, str]:
    """ISO 13400-2 §7.6: the tester answers an alive check request with its source address."""
    n = int(extra.get("alive_responses", 0))
    return n > 0, f"{n} alive check responses from the tester"


RULES: dict[str, Callable[[Frames, Ids, float, dict], tuple[bool, str]]] = {
    f.__name__: f for f in (cf_only_after_cts, cf_gap_127ms, cf_per_block, fc_to_each_responder,
                            no_fc_after_fault, fc_after_second_ff, no_request_while_pending,
                            alive_check_answered)}


@dataclass(frozen=True)
class Verdict:
    fault: str
    value: float
    verdict: str       # pass, fail, hung; error: the bench could not start the ECU / gateway
    exit_code: int | None
    seconds: float
    rule: str
    expected: str
    evidence: str


def judge(fault: DiagFault, value: float, exit_code: int | None, seconds: float,
          frames: Frames, ids: Ids, extra: dict) -> Verdict:
    expected = f"exit {fault.outcome}" + (f", {fault.rule}" if fault.rule else "")
    if exit_code is None:
        return Verdict(fault.name, value, "hung", None, seconds, fault.expect, expected,
                       f"no exit within {seconds:.0f} s: killed")
    ok_exit = {ANSWER: exit_code == 0, ERROR: exit_code != 0}.get(fault.outcome, True)
    notes = [f"exit {exit_code} after {seconds:.2f} s"]
    ok_rule = True
    if fault.rule:
        ok_rule, text = RULES[fault.rule](frames, ids, value, extra)
        notes.append(f"{fault.rule}: {text}")
    return Verdict(fault.name, value, "pass" if ok_exit and ok_rule else "fail", exit_code,
                   seconds, fault.expect, expected, "; ".join(notes))
