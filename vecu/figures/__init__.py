"""The seed papers' figures redrawn from vecu's own runs (`vecu figures`, docs/reproduction.md)."""

from __future__ import annotations

from pathlib import Path


def make_figures(out: Path, families: list[str], quick: bool = False) -> list[tuple[Path, str]]:
    """Write the PNGs of the families asked for into out; returns (path, one-line note) each."""
    from vecu.figures import manifold, speed, steering, throttle

    makers = {"throttle": throttle.make, "manifold": manifold.make, "steering": steering.make,
              "speed": speed.make}
    done: list[tuple[Path, str]] = []
    for fam in families:
        done += makers[fam](out, quick)
    return done
