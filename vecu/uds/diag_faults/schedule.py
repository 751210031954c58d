"""Which diagnostic fault is active now (windows in seconds, `@request=N`), and its FI_Event
frame for each start and end (FI_EvKind 31: vecu.uds.diag_faults.catalogue) — shared by the ECU's
and the gateway's fault engines."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from vecu.clock import NS_PER_S
from vecu.faults import FAULT_SOURCES
from vecu.uds.diag_faults.catalogue import DIAG_EV_KIND
from vecu.uds.diag_faults.setting import DiagFaultSetting

log = logging.getLogger("vecu.conformance")


class FaultSchedule:
    """settings in order (the first active wins); `target`: FI_EvMessageId (the CAN response
    ID or the DoIP logical address); fi_event: the FI_Event FrameCodec and send(frame) (None:
    no frames, events kept only)."""

    def __init__(self, settings: Sequence[DiagFaultSetting], target: int,
                 fi_event: Any = None, send: Callable[[Any], object] | None = None,
                 source: str = "api") -> None:
        self.settings = list(settings)
        self.target = target
        self._fi, self._send = fi_event, send
        self.source = source
        self.request_no = 0
        self.current: DiagFaultSetting | None = None
        self._on: set[int] = set()
        self.events: list[tuple[int, str, bool, float]] = []  # (t_ns, fault, start, value)

    def new_request(self, t_ns: int) -> DiagFaultSetting | None:
        """A request begins: count it, the fault that applies to it."""
        self.request_no += 1
        return self.update(t_ns, window_only=False)

    def update(self, t_ns: int, window_only: bool = True) -> DiagFaultSetting | None:
        """The active setting now; window_only (between requests): `@request=N` ones stay as
        they are."""
        t_s = t_ns / NS_PER_S
        now = {i for i, s in enumerate(self.settings)
               if (s.request is None or not window_only) and s.active(t_s, self.request_no)}
        if window_only:
            now |= {i for i in self._on if self.settings[i].request is not None}
        for i in sorted(self._on - now):
            self._announce(self.settings[i], False, t_ns)
        for i in sorted(now - self._on):
            self._announce(self.settings[i], True, t_ns)
        self._on = now
        self.current = self.settings[min(now)] if now else None
        return self.current

    def _announce(self, s: DiagFaultSetting, start: bool, t_ns: int) -> None:
        self.events.append((t_ns, s.fault.name, start, s.value))
        log.info("diagnostic fault %s %s", s, "on" if start else "off")
        if self._fi is not None and self._send is not None:
            self._send(self._fi.frame({
                "FI_EvMessageId": self.target, "FI_EvSignal": s.fault.code,
                "FI_EvKind": DIAG_EV_KIND, "FI_EvActive": int(start),
                "FI_EvSource": FAULT_SOURCES.get(self.source, 3), "FI_EvValue": s.value},
                t_ns / NS_PER_S))

    def summary(self) -> list[dict[str, object]]:
        return [{"t_s": t / NS_PER_S, "fault": name, "on": on, "value": v}
                for t, name, on, v in self.events]
