"""Security access seeds: a live ECU draws them from the OS's entropy, so a sniffed
seed/key pair does not unlock it again after a restart; a seed asked for (the simulated clock,
`vecu ecu --security-seed N`) makes them reproducible."""

from __future__ import annotations

import pytest

from vecu.assembly import build_functions
from vecu.bus import SinkBus
from vecu.cli import build_parser
from vecu.codec import DbcCodec
from vecu.config import RunConfig
from vecu.ecu.node import EcuNode
from vecu.uds.server import attach_uds


def _first_seeds(seed: int | None, starts: int = 5) -> list[bytes]:
    """The first seed of `starts` ECUs started anew, each as `vecu ecu` attaches its server."""
    seeds = []
    config = RunConfig(duration_s=600.0, kill_tps_at_s=None, speed=False, steering=False,
                       manifold=False)
    codec = DbcCodec()
    for _ in range(starts):
        ecu = EcuNode(SinkBus(), codec, build_functions(config, codec).enabled())
        uds = attach_uds(ecu, config.params.ecu.uds, seed)
        assert uds is not None
        assert uds.handle(b"\x10\x03", False, 0)[:2] == b"\x50\x03"
        response = uds.handle(b"\x27\x01", False, 0)
        assert response is not None and response[:2] == b"\x67\x01" and len(response) == 6
        seeds.append(response[2:])
    return seeds


def test_vecu_ecu_gives_a_new_seed_sequence_on_every_start():
    args = build_parser().parse_args(["ecu"])
    assert args.security_seed is None  # the OS's entropy unless asked for
    seeds = _first_seeds(args.security_seed)
    assert len(set(seeds)) == len(seeds)  # 5 starts, 5 seeds (a repeat: p < 3e-9)
    assert all(b != 0 for s in seeds for b in s)  # never a zero byte (never the "unlocked" seed)


@pytest.mark.parametrize("argv", [["ecu", "--security-seed", "7"]])
def test_a_seed_asked_for_gives_the_same_seeds_on_every_start(argv):
    seed = build_parser().parse_args(argv).security_seed
    assert seed == 7
    seeds = _first_seeds(seed, starts=3)
    assert len(set(seeds)) == 1
    assert _first_seeds(8, starts=1) != seeds[:1]
