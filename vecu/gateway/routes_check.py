"""Checks across the routes of one gateway config (routes_config): no loop (a frame that comes
back to a bus it left: each hop of a frame between buses is a route's match, as can-gw's hop
limit would otherwise cut it) and no target signal written by two routes."""

from __future__ import annotations

from vecu.gateway.config import _Check, _hex
from vecu.gateway.routes import RoutingConfig, SignalRoute

Node = tuple[str, int]  # (bus, CAN ID)


def check_routes(chk: _Check, config: RoutingConfig) -> None:
    _no_two_writers(chk, config)
    _no_loop(chk, config)


def _no_two_writers(chk: _Check, config: RoutingConfig) -> None:
    sends: dict[tuple[str, int], str] = {}  # (bus, CAN ID) a route sends -> the route
    for f in config.frame_routes:
        for out in ([f.new_id] if f.new_id is not None else [i for i, _ in f.ids]):
            _claim(chk, sends, (f.target, out), f.key, f.key + (".id" if f.new_id else ""))
    for r in config.signal_routes:
        fid = config.bus(r.target).codec[r.message].frame_id
        _claim(chk, sends, (r.target, fid), r.key, r.key + ".target")
    seen: dict[tuple[str, str, str], str] = {}
    for r in config.signal_routes:
        for m in r.signals:
            key = (r.target, r.message, m.target)
            if key in seen:
                raise chk.fail(f"{r.key}.signals.{m.target}",
                               f"{r.message}.{m.target} on bus {r.target!r} is already written by "
                               f"{seen[key]}")
            seen[key] = r.key


def _claim(chk: _Check, sends: dict[tuple[str, int], str], node: Node, route: str,
           key: str) -> None:
    other = sends.setdefault(node, route)
    if other != route:
        raise chk.fail(key, f"{_hex(node[1])} on bus {node[0]!r} is already sent by {other}")


def _edges(config: RoutingConfig, node: Node) -> list[tuple[str, Node]]:
    """(route key, the node it sends to) of every route that takes a frame at `node`."""
    bus, can_id = node
    if any(d.source == bus and can_id in d.ids for d in config.deny):
        return []
    out: list[tuple[str, Node]] = []
    for r in config.frame_routes:
        if r.source == bus and r.matches(can_id, can_id > 0x7FF or r.mask_extended):
            out.append((r.key, (r.target, can_id if r.new_id is None else r.new_id)))
    for s in config.signal_routes:
        if s.source == bus and can_id in _source_ids(config, s):
            out.append((s.key, (s.target, config.bus(s.target).codec[s.message].frame_id)))
    return out


def _source_ids(config: RoutingConfig, s: SignalRoute) -> set[int]:
    codec = config.bus(s.source).codec
    return {codec[m.message].frame_id for m in s.signals}


def _no_loop(chk: _Check, config: RoutingConfig) -> None:
    """From every route's first hop, follow the routes; a node met twice on one path: a loop."""
    starts: list[Node] = []
    for r in config.frame_routes:
        starts += [(r.source, i) for i, _ in r.ids]
        if r.id_mask is not None:
            starts.append((r.source, r.id_mask[0]))
    for s in config.signal_routes:
        starts += [(s.source, i) for i in _source_ids(config, s)]
    for start in starts:
        stack: list[tuple[Node, tuple[Node, ...], tuple[str, ...]]] = [(start, (start,), ())]
        while stack:
            node, path, keys = stack.pop()
            for key, nxt in _edges(config, node):
                if nxt in path:
                    hops = " -> ".join(f"{b} {_hex(i)}" for b, i in (*path, nxt))
                    first = keys[0] if keys else key
                    raise chk.fail(key, f"a loop with {first}: {hops}")
                stack.append((nxt, (*path, nxt), (*keys, key)))
