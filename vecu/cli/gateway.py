"""`vecu gateway`: a DoIP entity (ISO 13400-2) on TCP/UDP in front of the ECUs of a python-can
bus, and the routing between the CAN buses its config names ([buses.NAME], [[routes]],
[[deny]]), live on the wall clock like `vecu ecu` (docs/gateway.md)."""

from __future__ import annotations

import argparse
from typing import Any

from vecu import argtypes
from vecu.cli import configure_logging
from vecu.live.args import (
    add_bus_arguments,
    add_duration_argument,
    add_process_arguments,
    live_options,
)

STEP_NS = 1_000_000  # the gateway's loop: sockets, CAN frames, timers every 1 ms


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "gateway", help="a DoIP gateway (ISO 13400-2) in front of the ECUs on a CAN bus",
        description="A DoIP entity on TCP and UDP (default 127.0.0.1 port 13400): testers "
                    "discover it, activate routing and send UDS by logical address; each "
                    "request goes through ISO-TP to the ECU behind it and the answer comes "
                    "back. Without --config: 0x0010 -> 0x7E0/0x7E8, 0x0011 -> 0x7E1/0x7E9, "
                    "functional 0xE400 -> 0x7DF, the gateway itself at 0x1000 (docs/gateway.md).")
    p.add_argument("--config", metavar="GATEWAY.toml",
                   help="routes, VIN/EID/GID, DoIP settings (default: the shipped one, "
                        "--print-config)")
    p.add_argument("--print-config", action="store_true",
                   help="print the default config file and exit")
    add_bus_arguments(p)
    p.add_argument("--bus", action="append", default=[], type=argtypes.bus_override,
                   metavar="NAME=INTERFACE:CHANNEL",
                   help="open the config's bus NAME on this python-can interface and channel "
                        "instead of its [buses.NAME] arguments (repeatable)")
    p.add_argument("--doip-bind", default="127.0.0.1", metavar="ADDR",
                   help="IPv4 address of the DoIP sockets (default 127.0.0.1; 0.0.0.0: every "
                        "interface, needed for broadcast discovery)")
    p.add_argument("--doip-port", type=argtypes.bounded(0, 65535, integer=True), default=13400,
                   metavar="N", help="TCP_DATA and UDP_DISCOVERY port (default 13400)")
    add_duration_argument(p)
    p.add_argument("--seed", type=argtypes.seed, default=0,
                   help="seed of the announcement delay, 0..2**63-1 (default 0)")
    add_process_arguments(p)
    p.set_defaults(func=main, uses_kernels=False)


def main(args: argparse.Namespace) -> int:
    configure_logging(args.quiet)
    from vecu.gateway.config import DEFAULT_TOML, default_config, load_gateway_config

    if args.print_config:
        print(DEFAULT_TOML, end="" if DEFAULT_TOML.endswith("\n") else "\n")
        return 0
    config = load_gateway_config(args.config) if args.config else default_config()
    from vecu.errors import BadArgumentError
    from vecu.gateway.routes_config import load_routing_config

    routing = load_routing_config(args.config) if args.config else None
    if routing is not None and not routing.buses:
        routing = None
    if args.bus and routing is None:
        raise BadArgumentError("--bus names a bus of the config's [buses.NAME]: give --config "
                               "with buses to route between")

    from vecu.bus import BusNode
    from vecu.codec import DbcCodec
    from vecu.errors import UnavailableError
    from vecu.gateway.entity import DoipEntity
    from vecu.gateway.live_routing import LiveRouting
    from vecu.gateway.router import DiagRouter
    from vecu.gateway.settings import settings_of
    from vecu.live.process import LiveProcess
    from vecu.rng import rng_streams

    settings = settings_of(config)
    proc = LiveProcess(live_options(args, "gateway"), DbcCodec(), "TESTER",
                       own_ids=request_ids(config))
    entity: DoipEntity | None = None
    summary: dict[str, Any] | None = None
    buses: LiveRouting | None = None
    try:
        if routing is not None:  # every bus opened before the run, each error one line
            buses = LiveRouting(routing, tuple(args.bus))
        proc.consume_only({(r.response_id, r.extended_ids) for r in config.ecus})
        node = BusNode(proc.bus, "gateway")  # type: ignore[arg-type]  # LiveBus: python-can's send
        router = DiagRouter(node, config, proc.clock.now_ns)
        delay = float(rng_streams(args.seed, ("doip_announce",))["doip_announce"].uniform(
            0.0, settings.announce_wait_s))
        entity = DoipEntity(config, settings, router, node, delay, args.doip_bind,
                            args.doip_port)
        try:
            entity.open()
        except OSError as exc:
            raise UnavailableError(f"--doip-bind {args.doip_bind} --doip-port {args.doip_port}: "
                                   f"{exc.strerror or exc}") from None
        meter = proc.meter("gateway")

        def step(t_ns: int) -> None:
            entity.step(t_ns)  # DoIP in (requests submitted) and out
            router.step(t_ns)  # CAN in, requests out, replies to the testers (sent at once)
            if buses is not None:
                buses.step(t_ns)  # frames between the buses

        meter.stats = proc.sched.every(STEP_NS, meter.wrap(step), name="gateway", priority=10)
        proc.status_lines = lambda: [_status_line(entity)]
        proc.signal_ready()
        try:
            proc.run()
        finally:
            summary = proc.summary({"doip": entity.summary(), "routes": _routes(router),
                                    **({"routing": buses.summary()} if buses else {})})
            proc.write_summary(summary)
    finally:
        if entity is not None:
            entity.close()
        if buses is not None:
            buses.close()
        proc.close()
    if not args.quiet and summary is not None:
        print(format_gateway_summary(summary))
    return LiveProcess.end(summary)


def request_ids(config: Any) -> set[tuple[int, bool]]:
    """The CAN IDs the gateway sends on (requests and flow control): its own echoes."""
    out = {(config.functional_id, config.functional_addressing != "normal_11bit")}
    for r in config.ecus:
        out.add((r.request_id, r.extended_ids))
    return out


def _routes(router: Any) -> Any:
    from vecu.summary import to_json

    return to_json(router.summary())


def _status_line(entity: Any) -> str:
    s = entity.summary()
    return (f"  doip: {len(entity.conns)} connections, {sum(s['activations'].values())} "
            f"activations, {s['diag'].get('routed', 0)} routed, "
            f"{s['diag'].get('responses', 0)} responses, {s['bad_input_total']} bad inputs")


def format_gateway_summary(s: dict[str, Any]) -> str:
    d = s["doip"]
    return "\n".join([
        (f"vecu gateway: {s['elapsed_s']:.1f} s, DoIP on {d['bind']}:{d['port']}, CAN on "
         f"{s['interface']} {s['channel']}, stopped by {s['stopped_by']}"),
        (f"  {d['connections'].get('accepted', 0)} connections, activations {d['activations']}, "
         f"{d['diag'].get('routed', 0)} requests routed, {d['diag'].get('responses', 0)} "
         f"responses, diagnostic NACKs {d['diag_nacks']}"),
        (f"  bad input {d['bad_input_total']} (generic NACKs {d['generic_nacks']}), "
         f"handler errors {sum(d['handler_errors'].values())}"),
    ] + (routing_lines(s["routing"]) if "routing" in s else []))


def routing_lines(r: dict[str, Any]) -> list[str]:
    """The buses joined and each route's figures (vecu.cli.run's lines)."""
    from vecu.cli.run import gateway_lines

    buses = ", ".join(f"{k} ({v})" for k, v in r["buses"].items())
    return [f"  buses: {buses}; send errors {r['send_errors']}",
            *(f"  {ln}" for ln in gateway_lines(r))]
