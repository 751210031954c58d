"""Generated per-message code beside the codec's encoder / decoder: frame builders for a fixed
signal order (FrameCodec.frame(dict(zip(names, values)), ts) as one call make(ts, *values),
without the dict, the encode / CRC / Message call chain) and the receive range check.

The code is put together from the lines the codec's generated encoder uses for each signal
(vecu.codec.compile_fast_codec records them as EncodeParts), then the E2E protection
(autosar-e2e's protect, in place) and vecu.can_message's message, written out (return_lines).
A value the generated encoder would refuse (not a number, a raw value that does not fit) makes
the builder return `slow(ts, values)`, which is FrameCodec.frame with the dict: the same frame
either way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import can

from vecu.can_message import return_lines

Framer = Callable[..., can.Message]  # make(timestamp, *values in the names' order)
FrameCodecLike = Any  # vecu.codec.FrameCodec (which imports this module)


class _Refused(Exception):
    """A value the generated lines do not take (their `return None`): FrameCodec.frame decides."""


@dataclass(frozen=True)
class DecodeParts:
    """A generated decoder's pieces: its lines before the return (they read `data`), the
    expression of the values dict it returns and the namespace the lines use."""

    lines: list[str]
    values: str
    namespace: dict[str, object]


@dataclass(frozen=True)
class EncodeParts:
    """A generated encoder's pieces: per signal its lines after `v = values[name]` (they read
    v, OR the raw bits into `le` / `be` and `return None` on a value it cannot take), the
    expression of the payload bytes and the namespace the lines use."""

    blocks: dict[str, list[str]]
    payload: str
    namespace: dict[str, object]


def make_framer(fc: FrameCodecLike, names: tuple[str, ...], parts: EncodeParts | None) -> Framer:
    """FrameCodec.framer(names): compile_framer from the parts of the codec's generated encoder,
    or (None: it has none) a call of fc.frame with the dict."""
    if sorted(names) != sorted(s.name for s in fc.signals):
        raise ValueError(f"{fc.name}: framer names {list(names)} are not its signals")

    def slow(timestamp: float, values: tuple) -> can.Message:
        return fc.frame(dict(zip(names, values)), timestamp)

    if parts is None:  # no generated encoder: cantools through frame()
        return lambda timestamp, *values: slow(timestamp, values)
    return compile_framer(parts, names, frame_id=fc.frame_id, is_extended=fc.is_extended,
                          is_fd=fc.is_fd, length=fc.length,
                          protect=fc.e2e.protection.protector() if fc.e2e is not None else None,
                          slow=slow, label=fc.name)


def compile_framer(parts: EncodeParts, names: Sequence[str], *, frame_id: int,
                   is_extended: bool, is_fd: bool, length: int,
                   protect: Callable[[bytearray], None] | None,
                   slow: Callable[[float, tuple], can.Message], label: str) -> Framer:
    """make(ts, *values) for the signals `names` (every signal of the message, in any order)."""
    if sorted(names) != sorted(parts.blocks) or len(set(names)) != len(names):
        raise ValueError(f"{label}: framer names {list(names)} are not its signals "
                         f"{sorted(parts.blocks)}")
    args = [f"a{j}" for j in range(len(names))]
    fallback = f"return _slow(ts, ({', '.join(args)},))"
    # FrameCodec.encode also takes anything the generated lines raise on (round(inf)) to cantools
    src = [f"def make(ts, {', '.join(args)}):", "    try:", "        le = 0", "        be = 0"]
    for name in parts.blocks:  # the encoder's signal order
        src.append(f"        v = {args[names.index(name)]}")
        src.extend("    " + line.replace("return None", "raise _Refused")
                   for line in parts.blocks[name])
    src.append(f"        buf = bytearray({parts.payload})")
    src.extend(["    except Exception:", f"        {fallback}"])
    ns = dict(parts.namespace)
    if protect is not None:  # the message's AUTOSAR profile (autosar-e2e), in place
        ns["_protect"] = protect
        src.append("    _protect(buf)")
    ret, ret_names = return_lines("ts", frame_id, is_extended, "buf", length, is_fd)
    src.extend("    " + line for line in ret)
    ns.update(ret_names)
    ns.update(_slow=slow, _Refused=_Refused)
    exec(compile("\n".join(src) + "\n", f"<vecu framer {label}>", "exec"), ns)  # noqa: S102 (generated from the DBC layout)
    return ns["make"]  # type: ignore[return-value]  # exec'd: typed by the generator


def compile_range_check(checked: Sequence[tuple[str, float | None, float | None]], label: str
                        ) -> Callable[[Mapping[str, float]], list[str]]:
    """bad_values(values): the names among `checked` (name, lo, hi) whose value is present and
    NaN / inf or outside [lo, hi] (None: no bound), in that order; FrameCodec.bad_values as
    generated code (a test compares the two)."""
    src = ["def bad_values(values):", "    bad = []"]
    ns: dict[str, object] = {}
    src += _range_lines(checked, ns, may_lack=True)
    src.append("    return bad")
    exec(compile("\n".join(src) + "\n", f"<vecu range check {label}>", "exec"), ns)  # noqa: S102 (generated from the DBC ranges)
    return ns["bad_values"]  # type: ignore[return-value]  # exec'd: typed by the generator


def compile_decode_checked(decode: Callable[[bytes | bytearray], dict[str, float]],
                           checked: Sequence[tuple[str, float | None, float | None]], label: str,
                           complete: bool, parts: DecodeParts | None = None
                           ) -> Callable[[bytes | bytearray], tuple[dict[str, float], list[str]]]:
    """decode_checked(data) = (values, bad_values(values)) with values = decode(data): the
    receive path's decode and range check in one call (compile_range_check's tests; complete:
    decode's dict holds every signal, read without .get). parts (decode's own, from the
    codec's generator): its lines written out here instead of a call of decode."""
    if parts is None or not complete:
        src = ["def decode_checked(data):", "    values = _decode(data)", "    bad = []"]
        ns: dict[str, object] = {"_decode": decode}
    else:
        src = ["def decode_checked(data):", *parts.lines, f"    values = {parts.values}",
               "    bad = []"]
        ns = dict(parts.namespace)
    src += _range_lines(checked, ns, may_lack=not complete, prefix="_chk")
    src.append("    return values, bad")
    exec(compile("\n".join(src) + "\n", f"<vecu decode check {label}>", "exec"), ns)  # noqa: S102 (generated from the DBC ranges)
    return ns["decode_checked"]  # type: ignore[return-value]  # exec'd: typed by the generator


def _range_lines(checked: Sequence[tuple[str, float | None, float | None]],
                 ns: dict[str, object], may_lack: bool, prefix: str = "") -> list[str]:
    """Per checked signal (name, lo, hi) of `values`: bad.append(name) when its value is NaN /
    inf or outside [lo, hi] (None: no bound); may_lack: a signal values lacks is not checked.
    The bounds go into ns (as {prefix}_lo{i}, {prefix}_hi{i})."""
    src = []
    ns["_isfinite"] = math.isfinite
    for j, (name, lo, hi) in enumerate(checked):
        i = f"{prefix}{j}"
        ns[f"_lo{i}"], ns[f"_hi{i}"] = lo, hi
        src.append(f"    v = values.get({name!r})" if may_lack else f"    v = values[{name!r}]")
        if lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi):
            test = f"not (_lo{i} <= v <= _hi{i})"  # NaN and +-inf fail a finite bound too
        else:  # FrameCodec's own test
            test = "(not _isfinite(v)" + (f" or v < _lo{i}" if lo is not None else "") + (
                f" or v > _hi{i}" if hi is not None else "") + ")"
        src.append(f"    if {'v is not None and ' if may_lack else ''}{test}: bad.append({name!r})")
    return src
