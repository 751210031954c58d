"""The DBC sets the codec tests sweep: vecu's own (vecu.dbc + vecu_truth.dbc), then every
third-party DBC of shared/thirdparty (loaded non-strict, as `vecu` loads a user's file)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from vecu.codec import DbcCodec


def every_codec(thirdparty_dir: Path | None) -> Iterator[DbcCodec]:
    yield DbcCodec()
    if thirdparty_dir is not None:
        for path in sorted((thirdparty_dir / "dbc").glob("*.dbc")):
            yield DbcCodec([path], strict=False)
