"""A restbus from the user's databases: which messages, at which cycle, with which protection
and values. Everything is checked here, before anything is sent: each problem is one
BadFileError / BadArgumentError line naming the file, the message and the problem.

E2E.toml:

    [[e2e]]
    message = "ABS_Wheel"     # or id = 0x1B0
    profile = "P05"           # P01 | P02 | P04 | P05 | P07 | P11
    data_id = 0x01B0          # P02: data_id_list = [16 values]
    data_id_mode = "both"     # P01 / P11: both | alt | low | nibble
    offset = 0                # byte offset of the E2E header (default 0)
    length = 8                # bytes protected (default: the message's length)

A message without an entry keeps an ARXML's E2E properties as cantools reads them (profile from
the category, data IDs, protected length: arxml_protection) or vecu's own `<prefix>_CRC` /
`<prefix>_AliveCounter` layout (P11); else it is unprotected. ARXML properties vecu cannot apply
(a profile it does not send, a header the message cannot hold) are logged and leave the message
unprotected; the summary's `e2e` says where each message's protection came from.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vecu.codec import DbcCodec, FrameCodec
from vecu.e2e import PROFILES, E2EConfigError, E2EProtection
from vecu.errors import BadArgumentError, BadFileError
from vecu.restbus.node import SEND_TYPES, MessagePlan
from vecu.restbus.values import ValueSpec, build_source, parse_values
from vecu.rng import rng_streams
from vecu.tomlfile import read_toml

NS_PER_MS = 1_000_000
_log = logging.getLogger("vecu.restbus")
ON_CHANGE_POLL_MS = 10.0  # an on-change message without a cycle time is looked at this often


@dataclass(frozen=True)
class RestbusConfig:
    """What `vecu restbus` (or a scenario's [restbus] table) asks for."""

    databases: tuple[str, ...]
    nodes: tuple[str, ...] = ()
    e2e_path: str | None = None
    values_path: str | None = None
    default_cycle_ms: float | None = None  # for messages without a cycle time (else skipped)
    seed: int = 0
    exclude: frozenset[tuple[int, bool]] = frozenset()  # (CAN ID, extended) others send
    stagger_ms: float = 0.0  # message k's first frame at k x stagger_ms (mod its cycle)


def send_type_of(fc: FrameCodec) -> str:
    """cantools' send type (DBC GenMsgSendType, ARXML) as one of SEND_TYPES."""
    text = re.sub(r"[^a-z]", "", (fc.send_type or "").lower())
    if "ifactive" in text:
        return "if_active"
    if "cyclic" not in text and any(w in text for w in ("event", "spontan", "change",
                                                         "onwrite")):
        return "on_change"
    return "cyclic"


def _db_label(cfg: RestbusConfig) -> str:
    return ", ".join(cfg.databases)


NO_CYCLE = "no cycle time"  # the reason of a chosen message that is not sent (--default-cycle)


def select_messages(db: DbcCodec, cfg: RestbusConfig) -> tuple[list[FrameCodec], dict[str, str]]:
    """The messages the chosen nodes send (default: every node that sends a message with a
    cycle time, and sender-less messages with one) and every other message of the databases
    with the reason it is not sent: each one is accounted for."""
    messages = sorted(db.by_id.values(), key=lambda fc: (fc.frame_id, fc.is_extended))
    known = sorted({n for fc in messages for n in fc.senders})
    for node in cfg.nodes:
        if node not in known:
            raise BadArgumentError(f"--node {node}: no such sending node in {_db_label(cfg)} "
                                   f"(nodes: {', '.join(known) or 'none'})")
    if cfg.nodes:
        chosen = [fc for fc in messages if set(fc.senders) & set(cfg.nodes)]
    else:
        timed = [fc for fc in messages if fc.cycle_time_ms or cfg.default_cycle_ms]
        cyclic_nodes = {n for fc in timed for n in fc.senders}
        chosen = [fc for fc in messages if set(fc.senders) & cyclic_nodes
                  or (not fc.senders and fc in timed)]
    skipped: dict[str, str] = {}
    for fc in messages:
        if fc in chosen:
            continue
        senders = ", ".join(fc.senders)
        if cfg.nodes:
            skipped[fc.name] = (f"sent by {senders}, not a chosen --node" if senders
                                else "no sender (not a chosen --node)")
        else:
            skipped[fc.name] = (f"its sender {senders} sends nothing with a cycle time"
                                if senders else "no sender and no cycle time")
    excluded = [fc for fc in chosen if (fc.frame_id, fc.is_extended) in cfg.exclude]
    skipped.update((fc.name, "excluded (an ID vecu's own nodes send)") for fc in excluded)
    chosen = [fc for fc in chosen if fc not in excluded]
    timed = [fc for fc in chosen if fc.cycle_time_ms or cfg.default_cycle_ms
             or send_type_of(fc) == "on_change"]
    if not timed:
        who = f"node(s) {', '.join(cfg.nodes)}" if cfg.nodes else "any node"
        raise BadFileError(_db_label(cfg), f"no message sent by {who} has a cycle time "
                           "(GenMsgCycleTime / ARXML timing): nothing to send periodically; "
                           "give --default-cycle MS to send them anyway")
    skipped.update((fc.name, NO_CYCLE) for fc in chosen if fc not in timed)
    return timed, skipped


def parse_e2e(path: str, db: DbcCodec) -> dict[str, E2EProtection]:
    """E2E.toml -> {message name: protection}, every entry checked against its message."""
    table = read_toml(path)
    unknown = sorted(set(table) - {"e2e"})
    if unknown:
        raise BadFileError(path, f"unknown table {unknown[0]!r} (expected [[e2e]] entries)")
    entries = table.get("e2e", [])
    if not isinstance(entries, list):
        raise BadFileError(path, "'e2e' must be an array of tables ([[e2e]])")
    by_id = {fc.frame_id: fc for fc in db.by_id.values()}
    allowed = {"message", "id", "profile", "data_id", "data_id_list", "data_id_mode", "offset",
               "length"}
    out: dict[str, E2EProtection] = {}
    for n, e in enumerate(entries, 1):
        where = f"[[e2e]] #{n}"
        extra = sorted(set(e) - allowed)
        if extra:
            raise BadFileError(path, f"{where}: unknown key {extra[0]!r} "
                               f"(keys: {', '.join(sorted(allowed))})")
        if "message" in e:
            if e["message"] not in db:
                raise BadFileError(path, f"{where}: no message {e['message']!r} in the "
                                   "database(s)")
            fc = db[e["message"]]
        elif isinstance(e.get("id"), int) and e["id"] in by_id:
            fc = by_id[e["id"]]
        else:
            raise BadFileError(path, f"{where}: needs message = \"NAME\" or id = CAN ID of a "
                               f"message in the database(s) (got {e.get('id')!r})")
        where = f"{fc.name} (0x{fc.frame_id:X})"
        if "profile" not in e:
            raise BadFileError(path, f"{where}: no profile (P01 | P02 | P04 | P05 | P07 | P11)")
        try:
            prot = E2EProtection(
                str(e["profile"]), data_id=int(e.get("data_id", fc.frame_id & 0xFFFF)),
                data_id_list=tuple(int(x) for x in e.get("data_id_list", ())),
                data_id_mode=str(e.get("data_id_mode", "both")), offset=int(e.get("offset", 0)),
                length=int(e.get("length", 0)))
        except (E2EConfigError, TypeError, ValueError) as exc:
            raise BadFileError(path, f"{where}: {exc}") from None
        problem = prot.fits(fc.length)
        if problem:
            raise BadFileError(path, f"{where}: message too short for its E2E header: {problem}")
        out[fc.name] = prot
    return out


# cantools hands over an END-TO-END-PROFILE's CATEGORY (or an E2E transformer's PROFILE-NAME)
# as written: AUTOSAR's names are PROFILE_01 .. PROFILE_22, tools also write Profile5, P05,
# E2E_P05. A letter after the number is another profile (PROFILE_04m: P04 plus source ID and
# message type), not the one of that number.
_CATEGORY = re.compile(r"(?:PROFILE|P)0*(\d+)(M?)$")


def arxml_profile(category: str | None, n_data_ids: int) -> str:
    """The profile an ARXML's E2E category names (P01 .. P22); without a number in it, the one
    cantools' own profile functions assume from the data IDs (16: P02, 1: P05). Raises
    E2EConfigError naming what it cannot map."""
    text = re.sub(r"[^A-Z0-9]", "", (category or "").upper())
    m = _CATEGORY.search(text)
    if m is None:
        by_count = {16: "P02", 1: "P05"}.get(n_data_ids)
        if by_count is None:
            raise E2EConfigError(f"E2E category {category!r} names no profile and "
                                 f"{n_data_ids} data IDs fit none (16: P02, 1: P05)")
        return by_count
    name = f"P{int(m.group(1)):02d}{m.group(2).lower()}"
    if name not in PROFILES:
        raise E2EConfigError(f"E2E category {category!r} is profile {name}, which vecu does "
                             f"not send (known: {', '.join(PROFILES)})")
    return name


def arxml_protection(fc: FrameCodec) -> E2EProtection | None:
    """The message's ARXML E2E properties as cantools reads them (category, data IDs, protected
    length; header at byte 0, data ID mode "both": cantools reads neither), None without any.
    Raises E2EConfigError when the message has properties vecu cannot apply."""
    props = fc.arxml_e2e
    if props is None:
        return None
    ids = props.data_ids
    if not ids:
        raise E2EConfigError(f"E2E category {props.category!r} without data IDs")
    name = arxml_profile(props.category, len(ids))
    if PROFILES[name].data_id_bits == 0:
        prot = E2EProtection(name, data_id_list=ids, length=props.payload_length or 0)
    elif len(ids) != 1:
        raise E2EConfigError(f"{name} takes one data ID, the ARXML gives {len(ids)}")
    else:
        prot = E2EProtection(name, data_id=ids[0], length=props.payload_length or 0)
    problem = prot.fits(fc.length)
    if problem:
        raise E2EConfigError(problem)
    return prot


def protection_of(fc: FrameCodec, e2e: dict[str, E2EProtection], origin: str
                ) -> tuple[E2EProtection | None, str]:
    """(the message's protection, where it comes from): E2E.toml, else the ARXML's properties,
    else vecu's <prefix>_CRC / _AliveCounter layout. ARXML properties vecu cannot apply are
    logged; without vecu's layout the message goes out unprotected (source "none: why")."""
    if fc.name in e2e:
        return e2e[fc.name], "E2E.toml"
    unused = "none"
    try:
        prot = arxml_protection(fc)
    except E2EConfigError as exc:
        _log.warning("restbus: %s: %s (0x%X): ARXML E2E properties not applied: %s (an "
                     "[[e2e]] entry in E2E.toml overrides them)", origin, fc.name, fc.frame_id,
                     exc)
        prot, unused = None, f"none: ARXML E2E not applied: {exc}"
    if prot is not None:
        return prot, f"ARXML ({fc.arxml_e2e.category if fc.arxml_e2e else None})"
    if fc.e2e is not None:
        return fc.e2e.protection, "vecu layout"
    return None, unused


def build_plans(cfg: RestbusConfig) -> tuple[list[MessagePlan], dict[str, str], DbcCodec]:
    """(plans, every message not sent with its reason, the databases) of cfg; raises the
    one-line errors."""
    for p in cfg.databases:
        if not Path(p).is_file():
            raise BadFileError(p, "no such database file")
    db = DbcCodec(cfg.databases, strict=False)
    chosen, skipped = select_messages(db, cfg)
    e2e = parse_e2e(cfg.e2e_path, db) if cfg.e2e_path else {}
    specs = _values(cfg, db)
    streams = rng_streams(cfg.seed, tuple(f"restbus.{fc.name}" for fc in chosen))
    base = Path(cfg.values_path).parent if cfg.values_path else Path(".")
    plans: list[MessagePlan] = []
    for fc in chosen:
        start = {s.name: _clip(fc.start_values[s.name], s.minimum, s.maximum)
                 for s in fc.signals}
        sources: dict[str, Any] = {name: (lambda t, v=v: v) for name, v in start.items()}
        for spec in specs.get(fc.name, []):
            sig = fc.signal(spec.signal)
            sources[spec.signal] = build_source(spec, sig.minimum, sig.maximum,
                                                streams[f"restbus.{fc.name}"], base,
                                                str(cfg.values_path))
        send = send_type_of(fc)
        cycle = fc.cycle_time_ms or cfg.default_cycle_ms or ON_CHANGE_POLL_MS
        prot, source = protection_of(fc, e2e, _db_label(cfg))
        period = round(cycle * NS_PER_MS)
        offset = round(len(plans) * cfg.stagger_ms * NS_PER_MS) % period
        plans.append(MessagePlan(fc, period, send, prot, sources, start, offset, source))
    assert all(p.send_type in SEND_TYPES for p in plans)
    return plans, skipped, db


def _clip(v: float, lo: float | None, hi: float | None) -> float:
    if lo is not None and v < lo:
        return float(lo)
    if hi is not None and v > hi:
        return float(hi)
    return v


def _values(cfg: RestbusConfig, db: DbcCodec) -> dict[str, list[ValueSpec]]:
    if not cfg.values_path:
        return {}
    specs = parse_values(read_toml(cfg.values_path), cfg.values_path)
    out: dict[str, list[ValueSpec]] = {}
    for spec in specs:
        if spec.message not in db:
            raise BadFileError(cfg.values_path, f"{spec.message}.{spec.signal}: no message "
                               f"{spec.message!r} in the database(s)")
        if spec.signal not in db[spec.message].ranges:
            raise BadFileError(cfg.values_path, f"{spec.message}.{spec.signal}: message "
                               f"{spec.message} has no signal {spec.signal!r}")
        out.setdefault(spec.message, []).append(spec)
    return out

