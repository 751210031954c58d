"""Live calibration: which `ecu.*` leaves the running ECU takes, and how.

A calibration acts as on a real ECU: the new value is checked (the leaf's bounds, its config's
own checks, the tree's validation) and, if accepted, used from the ECU's next tick; a refused
value changes nothing. `Calibrator.apply(tree)` is the one way a new calibration reaches the
functions, for an XCP write and for a timed set (`RunConfig.calibrations`) alike, so the two
give the same run.

LIVE lists the subtrees the ECU takes live (a registry: a new entry = a subtree whose users can
take a new value mid-run). Every other leaf is READ_ONLY in the A2L (it shapes objects built at
start, e.g. the estimator's model) and an XCP write to it is refused (ERR_WRITE_PROTECTED).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from vecu import params as ptree
from vecu.ecu.node import EcuNode

# subtree (under ecu.) -> how the node takes its new value
LIVE: dict[str, Callable[[EcuNode, Any], None]] = {
    "throttle.tps_monitor": lambda node, cfg: _monitor(node, "tps", cfg),
    "speed.wheel_monitor": lambda node, cfg: _monitor(node, "wheel", cfg),
    "steering.monitor": lambda node, cfg: _monitor(node, "swa", cfg),
}


def _monitor(node: EcuNode, name: str, cfg: Any) -> None:
    mon = node.monitors.get(name)
    if mon is not None:
        mon.recalibrate(cfg)


def is_live(path: str) -> bool:
    """Whether the leaf at `path` (under ecu.) is taken by the running ECU."""
    return any(path == p or path.startswith(p + ".") for p in LIVE)


class Calibrator:
    """The node's calibration (the ecu subtree) and its changes mid-run."""

    def __init__(self, node: EcuNode, ecu_tree: Any,
                 validate: Callable[[Any], None] | None = None) -> None:
        """validate(ecu_tree) raises ParamError for a tree the run cannot take (the harness
        passes config.validate_tree on the whole tree)."""
        self.node = node
        self.tree = ecu_tree
        self._validate = validate
        self.changes: list[tuple[int, str, Any]] = []  # (t_ns, path, value) applied

    def check(self, sets: list[tuple[str, Any]], base: Any = None) -> Any:
        """`base` (default: the ECU's tree) with (path under ecu., value) pairs applied and
        checked; ParamError else."""
        try:
            tree = ptree.apply_sets(self.tree if base is None else base, sets)
        except ptree.ParamError as exc:  # name the leaf by its whole path
            message = str(exc)
            for path, _ in sets:
                message = message.replace(f"'{path}", f"'ecu.{path}")
            raise ptree.ParamError(message) from None
        if self._validate is not None:
            self._validate(tree)
        return tree

    def apply(self, tree: Any, t_ns: int) -> None:
        """Make `tree` the ECU's calibration: each live subtree that changed is handed over."""
        for prefix, take in LIVE.items():
            new = ptree.get(tree, prefix)
            if new != ptree.get(self.tree, prefix):
                take(self.node, new)
        for leaf in ptree.differences(tree, self.tree):
            self.changes.append((t_ns, leaf.path, leaf.value))
        self.tree = tree

    def set(self, sets: list[tuple[str, Any]], t_ns: int) -> None:
        """check() then apply(): a timed set; ParamError for a refused value."""
        self.apply(self.check(sets), t_ns)
