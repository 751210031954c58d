"""DBC codecs: the one place where cantools encodes and decodes frames (docs/architecture.md).

One concept per module, as cantools lays out database/can/:

- database: DBC / ARXML / KCD / SYM files into one cantools database; DbcCodec, shared_codec;
- message: FrameCodec, one message compiled once (encode, decode, range check, frames);
- source: the generator of each message's one source text (tests/codec/golden/);
- signals: what the codec reads of a signal (SignalInfo, bit position, ranges, start values);
- e2e_layout: a message's AUTOSAR E2E P11 header (E2ELayout);
- blocks: many payloads of one message at once with numpy (BlockLayout, BlockChecks).
"""

from vecu.codec.blocks import BlockChecks, BlockField, BlockLayout
from vecu.codec.database import (
    DEFAULT_DBC,
    TRUTH_DBC,
    DbcCodec,
    builtin_dbc_dir,
    builtin_dbc_path,
    load_database,
    shared_codec,
)
from vecu.codec.e2e_layout import DbcLoadError, E2ELayout
from vecu.codec.message import FrameCodec, Framer, Values
from vecu.codec.signals import ArxmlE2E, SignalInfo

__all__ = [
    "DEFAULT_DBC", "TRUTH_DBC", "ArxmlE2E", "BlockChecks", "BlockField", "BlockLayout", "DbcCodec",
    "DbcLoadError", "E2ELayout", "FrameCodec", "Framer", "SignalInfo", "Values", "builtin_dbc_dir",
    "builtin_dbc_path",
    "load_database", "shared_codec",
]
