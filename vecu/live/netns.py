"""Run a command inside a private network namespace where udp_multicast works on loopback.

`unshare -rn` (user + network namespace, no root needed) or, failing that, `unshare -n` (root);
inside: loopback up and a route for the multicast group on it. The machine's own network
configuration is never touched: the namespace and its route vanish with the command.
"""

from __future__ import annotations

import functools
import shutil
import subprocess
import sys

from vecu.live.children import run_bounded
from vecu.live.options import UDP_DEFAULT_GROUP

SETUP = "ip link set lo up && ip route add {group}/32 dev lo && exec \"$@\""


def _prefixes() -> list[list[str]]:
    return [["unshare", "-rn"], ["unshare", "-n"]]


def wrap(argv: list[str], prefix: list[str], group: str = UDP_DEFAULT_GROUP) -> list[str]:
    return [*prefix, "sh", "-c", SETUP.format(group=group), "sh", *argv]


@functools.lru_cache(maxsize=1)
def namespace_prefix() -> tuple[list[str] | None, str]:
    """(unshare prefix that works here, or None; the reason when none does)."""
    for tool in ("unshare", "ip", "sh"):
        if shutil.which(tool) is None:
            return None, f"'{tool}' not found"
    try:
        import msgpack  # noqa: F401  (python-can's udp_multicast needs it)
    except ImportError:
        return None, "msgpack missing: install python-can[multicast]"
    reasons = []
    for prefix in _prefixes():
        try:
            res = run_bounded(wrap(["true"], prefix), timeout=20)
        except (OSError, subprocess.TimeoutExpired) as exc:
            reasons.append(f"{' '.join(prefix)}: {exc}")
            continue
        if res.returncode == 0:
            return prefix, ""
        reasons.append(f"{' '.join(prefix)}: {res.stderr.strip() or res.returncode}")
    return None, "no private network namespace: " + "; ".join(reasons)


def run_in_namespace(argv: list[str], timeout: float) -> subprocess.CompletedProcess:
    """Run argv in a fresh private network namespace, killed with everything it started after
    `timeout` s (TimeoutExpired) or when this process dies; RuntimeError when no namespace is
    possible."""
    prefix, reason = namespace_prefix()
    if prefix is None:
        raise RuntimeError(reason)
    return run_bounded(wrap(argv, prefix), timeout=timeout)


def python_module(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]
