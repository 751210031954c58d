"""Live command-line options: the parser's defaults agree with LiveOptions (args.py keeps
python-can out of the parser's imports, so the spin default is written twice)."""

from __future__ import annotations

import argparse

from vecu.live.args import add_live_arguments, live_options
from vecu.live.options import DEFAULT_SPIN_US, LiveOptions


def test_spin_default_is_the_live_options_default():
    p = argparse.ArgumentParser()
    add_live_arguments(p)
    opts = live_options(p.parse_args([]), "ecu")
    assert opts.spin_us == DEFAULT_SPIN_US == LiveOptions(role="ecu").spin_us
