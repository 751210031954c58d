"""Reading a TOML file the user named (scenarios, campaigns, signal maps): every way it can fail
is one BadFileError line naming the file (no such file, unreadable, not UTF-8 with the byte and
its line, TOML syntax with the parser's first line)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]  # the same API under the 3.10 backport's name

from vecu.errors import BadFileError


def read_toml(path: str | Path, error: type[BadFileError] = BadFileError) -> dict[str, Any]:
    """The parsed file, or `error(path, problem)` (a BadFileError subclass) on any problem."""
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise error(path, "no such file") from None
    except OSError as exc:
        raise error(path, f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:  # tomllib decodes the bytes as UTF-8
        line = exc.object[:exc.start].count(b"\n") + 1
        raise error(path, f"not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset "
                          f"{exc.start}, line {line}): TOML files must be UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(path, f"TOML syntax error: {exc}".splitlines()[0]) from None
