"""The seed papers' figures redrawn from vecu's own runs (`vecu figures`, docs/reproduction.md).

FAMILIES is the registry: one module per family, vecu.figures.<name>, with
make(out, quick) -> [(path, note)]; imported only when its figures are made.
"""

from __future__ import annotations

import importlib
from pathlib import Path

FAMILIES: tuple[str, ...] = ("throttle", "manifold", "steering", "speed")


def make_figures(out: Path, families: list[str], quick: bool = False) -> list[tuple[Path, str]]:
    """Write the PNGs of the families asked for into out; returns (path, one-line note) each."""
    done: list[tuple[Path, str]] = []
    for fam in families:
        done += importlib.import_module(f"vecu.figures.{fam}").make(out, quick)
    return done
