"""Seeded random streams: every random source in vecu comes from here (named, independent)."""

from __future__ import annotations

import numpy as np


def rng_streams(seed: int, names: tuple[str, ...]) -> dict[str, np.random.Generator]:
    """Independent, named random streams from one seed (adding a stream never shifts another)."""
    out = {}
    for name in names:
        entropy = [seed] + [ord(c) for c in name]
        out[name] = np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy)))
    return out
