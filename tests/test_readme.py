"""What a new user reads first: the README's first screen (two set-up commands), its command
table (every subcommand), no internal issue numbers in the README, docs/*.md or any --help, and
the numbers table held to the bench's figures by key (benchmarks/readme-bench.json, the keys
checked against what `vecu bench --quick --json` prints)."""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from vecu.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text(encoding="utf-8")
STORED = json.loads((REPO / "benchmarks" / "readme-bench.json").read_text())
ISSUE = re.compile(r"\b[Ii]ssues?\s+#?\d")

# README numbers-table row (its first cell) -> (bench JSON key, the figure as the row prints it)
BENCH_FIGURES: list[tuple[str, str, str]] = [
    ("`vecu run`, simulated clock", "run_backends[kernels=numba].x_realtime", "{:.1f}× real time"),
    ("`vecu run`, simulated clock", "run_backends[kernels=python].x_realtime", "{:.1f}× without"),
    ("`vecu run`, simulated clock",
     "run_backends[kernels=numba].throttle_estimator_alone_us_per_tick", "alone {:.2f} µs"),
    ("`vecu run`, simulated clock", "ecu.us_per_tick", "ECU alone {:.1f} µs"),
    ("`vecu replay`, 60 s", "replay.fast[trace=drive.blf].x_realtime", "{:.1f}× real time from"),
    ("`vecu replay`, 60 s", "replay.fast[trace=drive.log].x_realtime", "{:.1f}× from `.log`"),
    ("`vecu replay`, 60 s", "replay.fast[trace=drive.blf].read_share", "{:.3f} / "),
    ("`vecu replay`, 60 s", "replay.fast[trace=drive.log].read_share", " / {:.3f}"),
]


def lookup(data: Any, key: str) -> Any:
    """`a.b[field=value].c` in a bench JSON: dicts by name, list items by one field's value."""
    for part in re.split(r"\.(?![^\[]*\])", key):  # dots inside [...] belong to a value
        m = re.fullmatch(r"(\w+)(?:\[(\w+)=([^\]]+)\])?", part)
        assert m, key
        data = data[m.group(1)]
        if m.group(2):
            data = next(item for item in data if str(item[m.group(2)]) == m.group(3))
    return data


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return {name: child for action in parser._actions
            if isinstance(action, argparse._SubParsersAction)
            for name, child in action.choices.items()}


def _all_parsers() -> list[argparse.ArgumentParser]:
    out, stack = [], [build_parser()]
    while stack:
        p = stack.pop()
        out.append(p)
        stack.extend(_subparsers(p).values())
    return out


def _table(heading: str) -> str:
    """The README section under `## heading`."""
    return README.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]


def test_the_first_screen_has_exactly_two_set_up_commands():
    first = README.split("```bash\n", 1)[1].split("```", 1)[0]
    assert [ln.split()[:2] for ln in first.strip().splitlines()] == [["pip", "install"]] * 2


def test_the_command_table_names_every_subcommand():
    table = _table("Command line")
    for name, parser in _subparsers(build_parser()).items():
        assert f"`vecu {name}" in table, f"README command table: no `vecu {name}`"
        for sub in _subparsers(parser):
            assert re.search(rf"`vecu {name} {sub}\b", table), \
                f"README command table: no `vecu {name} {sub}`"


def test_no_internal_issue_numbers_where_a_user_reads():
    found = [f"{path.relative_to(REPO)}: {m.group(0)!r}"
             for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
             for m in ISSUE.finditer(path.read_text(encoding="utf-8"))]
    found += [f"{p.prog} --help: {m.group(0)!r}" for p in _all_parsers()
              for m in ISSUE.finditer(p.format_help())]
    assert not found, found


def test_the_numbers_table_quotes_the_stored_bench_figures():
    table = _table("Determinism and numbers")
    rows = {row.split("|")[1].strip(): row for row in table.splitlines() if row.startswith("| ")}
    for start, key, shown in BENCH_FIGURES:
        (row,) = [r for first, r in rows.items() if first.startswith(start)]
        figure = shown.format(lookup(STORED, key))
        assert figure in row, \
            f"README row {start!r}: expected {figure!r} ({key} in benchmarks/readme-bench.json)"


@pytest.mark.slow
def test_the_stored_keys_are_what_the_bench_prints(tmp_path):
    """The keys the README is held to exist in `vecu bench --quick --json` today, as finite
    numbers (~60 s: the quick pipeline, ecu and replay groups)."""
    groups = sorted({key.split(".")[0].split("[")[0] for _, key, _ in BENCH_FIGURES}
                    - {"run_backends"} | {"pipeline"})
    done = subprocess.run([sys.executable, "-m", "vecu", "bench", "--quick", "--only",
                           ",".join(groups), "--json"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=900, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    live = json.loads(done.stdout)
    for _, key, _ in BENCH_FIGURES:
        value = lookup(live, key)
        assert isinstance(value, (int, float)) and math.isfinite(value) and value > 0, key
