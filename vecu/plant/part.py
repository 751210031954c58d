"""What a plant part is: a physical system on the plant node that steps at its own rate (a
multiple of the 1 ms base tick) and sends its sensor frames; and the payloads of frames encoded
ahead in blocks (FrameCodec.encode_rows), which parts send as they are."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import can
import numpy as np

Send = Callable[[can.Message], bool]


class PlantPart(Protocol):
    name: str
    period_ns: int

    def tick(self, t_ns: int, send: Send) -> None: ...


def payload_rows(encoded: tuple[np.ndarray, np.ndarray] | None, n: int
                 ) -> list[bytearray | None]:
    """Per row its payload (a fresh bytearray, each sent once), None where the row is left to
    the framer (or every row, without a block encoding)."""
    if encoded is None:
        return [None] * n
    payloads, left = encoded
    size = payloads.shape[1]
    blob = payloads.tobytes()
    out: list[bytearray | None] = [bytearray(blob[i:i + size]) for i in range(0, n * size, size)]
    for i in np.flatnonzero(left).tolist():
        out[i] = None
    return out
