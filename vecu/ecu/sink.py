"""Where the ECU's frames go besides the bus: an estimate sink (trace replay: the truth scorer
and the `--out` writer) takes each frame the ECU sends with the values it carries, so that
nothing decodes a frame the ECU has just encoded."""

from __future__ import annotations

from typing import Protocol

import can

from vecu.codec import Values


class EstimateSink(Protocol):
    """Takes every frame the ECU node sends, as it goes on the bus."""

    def on_estimate(self, values: Values | None, msg: can.Message, t_ns: int) -> None:
        """msg sent at the ECU's time t_ns; values: the signals it carries in the DBC's order
        as its decoder would give them (the generated frame()'s second result, FrameCodec.framer),
        None for a frame not made from values (ECU_Status, ECU_Diag, a diagnostic response)."""
