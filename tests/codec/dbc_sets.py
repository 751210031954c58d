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


def every_message(request, with_thirdparty: bool) -> Iterator:
    """Every FrameCodec of every_codec: vecu's DBCs, plus the third-party ones (the
    `thirdparty` fixture, through the test's request) when with_thirdparty."""
    tp = request.getfixturevalue("thirdparty") if with_thirdparty else None
    for db in every_codec(tp):
        yield from db.by_id.values()
