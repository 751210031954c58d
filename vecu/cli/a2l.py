"""`vecu a2l`: the A2L (ASAM MCD-2 MC 1.7) of the ECU's XCP slave, from the parameter tree."""

from __future__ import annotations

import argparse
import sys

from vecu import argtypes
from vecu.cli import add_fmu_options, add_set_option, param_sets, with_fmu
from vecu.live.args import add_function_switches, function_switches


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("a2l", help="write the A2L of the ECU's XCP slave (measure, calibrate)",
                       description="The A2L that describes the virtual ECU's XCP-on-CAN slave: "
                                   "every numeric ecu.* leaf a CHARACTERISTIC (unit, bounds, "
                                   "address in the calibration segment), the ECU's estimates, "
                                   "sensor inputs, monitor and DTC states MEASUREMENTs, IF_DATA "
                                   "XCP with the CAN IDs (ecu.xcp.master_id / slave_id) and the "
                                   "DAQ events. Give the same --set as to `vecu ecu` (docs/xcp.md).")
    p.add_argument("--out", type=argtypes.output("file", ".a2l"), metavar="FILE.a2l", help="write here (default: standard output)")
    add_set_option(p, "ecu.*: as the ECU will run")
    add_function_switches(p, "as `vecu ecu --no-{}`")
    add_fmu_options(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from vecu.assembly import build_functions
    from vecu.bus import SinkBus
    from vecu.config import RunConfig
    from vecu.ecu.node import EcuNode
    from vecu.errors import BadArgumentError
    from vecu.functions import function_codec
    from vecu.runner import attach_xcp_server

    config = with_fmu(RunConfig(kill_tps_at_s=None, **function_switches(args),  # type: ignore[arg-type]  # the functions' bool switches
                                ), args).with_params(param_sets(args, only="ecu."))
    config.validate()
    if not config.params.ecu.xcp.enabled:
        raise BadArgumentError("ecu.xcp.enabled is false: the ECU serves no XCP, so no A2L")
    codec = function_codec(config.params.ecu.instance, config)  # + plug-ins' and an FMU's DBCs
    bus = SinkBus()
    try:
        node = EcuNode(bus, codec, build_functions(config, codec).enabled())
        server = attach_xcp_server(node, config)
        assert server is not None
        text = server.a2l()
    finally:
        bus.shutdown()
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        with open(args.out, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as exc:
        raise BadArgumentError(f"--out {args.out}: {exc.strerror or exc}") from None
    n_char = text.count("/begin CHARACTERISTIC")
    n_meas = text.count("/begin MEASUREMENT")
    print(f"vecu a2l: {args.out}: {n_char} characteristics ({n_char - text.count('READ_ONLY')} "
          f"calibratable live), {n_meas} measurements; XCP on CAN 0x"
          f"{config.params.ecu.xcp.master_id:X} -> 0x{config.params.ecu.xcp.slave_id:X}")
    return 0
