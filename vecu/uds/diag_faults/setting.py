"""One diagnostic fault switched on: `NAME[=VALUE][@T0[-T1]]` or `NAME[=VALUE]@request=N`
(the command line's --diag-fault, a scenario's [[diag_faults]] table, or code)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from vecu.errors import BadArgumentError
from vecu.uds.diag_faults.catalogue import DiagFault, fault

_SPEC = re.compile(r"^\s*([A-Za-z0-9_-]+)\s*(?:=\s*([^@\s]+))?\s*(?:@\s*(.+?))?\s*$")
_WINDOW = re.compile(r"^([0-9.]+)(?:-([0-9.]+))?$")
_REQUEST = re.compile(r"^request\s*=\s*([0-9]+)$")


@dataclass(frozen=True)
class DiagFaultSetting:
    """`fault` with `value` from start_s to end_s (None: to the end), or only on the
    `request`-th request (1-based) the ECU / gateway receives."""

    fault: DiagFault
    value: float
    start_s: float = 0.0
    end_s: float | None = None
    request: int | None = None

    def active(self, t_s: float, request_no: int) -> bool:
        if self.request is not None:
            return request_no == self.request
        return t_s >= self.start_s and (self.end_s is None or t_s < self.end_s)

    def __str__(self) -> str:
        text = self.fault.name + (f"={self.value:g}" if self.fault.param else "")
        if self.request is not None:
            return f"{text}@request={self.request}"
        if self.start_s or self.end_s is not None:
            end = "" if self.end_s is None else f"-{self.end_s:g}"
            return f"{text}@{self.start_s:g}{end}"
        return text


def _number(text: str, what: str) -> float:
    try:
        return float(int(text, 0)) if re.match(r"^[+-]?(0x[0-9a-fA-F]+|[0-9]+)$", text) \
            else float(text)
    except ValueError:
        raise BadArgumentError(f"diagnostic fault {what}: bad number {text!r}") from None


def setting(name: str, value: float | None = None, start_s: float = 0.0,
            end_s: float | None = None, request: int | None = None) -> DiagFaultSetting:
    """A checked setting (BadArgumentError: unknown name, value out of range, bad window)."""
    rec = fault(name)
    v = rec.checked(value)
    if start_s < 0 or (end_s is not None and end_s <= start_s):
        raise BadArgumentError(f"diagnostic fault {rec.name}: bad window {start_s:g}-{end_s}")
    if request is not None and request < 1:
        raise BadArgumentError(f"diagnostic fault {rec.name}: request=N counts from 1")
    return DiagFaultSetting(rec, v, start_s, end_s, request)


def parse_setting(text: str) -> DiagFaultSetting:
    """NAME[=VALUE][@T0[-T1]] or NAME[=VALUE]@request=N (VALUE decimal or 0x-hex)."""
    m = _SPEC.match(text)
    if m is None:
        raise BadArgumentError(f"bad diagnostic fault {text!r}: expected "
                               "NAME[=VALUE][@T0[-T1]] or NAME[=VALUE]@request=N")
    name, value, when = m.groups()
    v = None if value is None else _number(value, name)
    if when is None:
        return setting(name, v)
    req = _REQUEST.match(when)
    if req:
        return setting(name, v, request=int(req.group(1)))
    win = _WINDOW.match(when)
    if win is None:
        raise BadArgumentError(f"bad diagnostic fault window {when!r} in {text!r}: expected "
                               "T0, T0-T1 (seconds) or request=N")
    return setting(name, v, _number(win.group(1), name),
                   None if win.group(2) is None else _number(win.group(2), name))


def setting_from_table(entry: dict[str, Any], where: str) -> DiagFaultSetting:
    """A scenario's [[diag_faults]] entry: name, value, at_s, until_s, request."""
    known = {"name", "value", "at_s", "until_s", "request"}
    extra = sorted(set(entry) - known)
    if extra or "name" not in entry:
        raise BadArgumentError(f"{where}: [[diag_faults]] needs name (and optionally value, "
                               f"at_s, until_s, request); got {sorted(entry)}")
    return setting(str(entry["name"]), entry.get("value"), float(entry.get("at_s", 0.0)),
                   entry.get("until_s"), entry.get("request"))
