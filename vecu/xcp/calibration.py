"""Live calibration: which `ecu.*` leaves the running ECU takes, and how.

A calibration acts as on a real ECU: the new value is checked (the leaf's bounds, its config's
own checks, the tree's validation) and, if accepted, used from the ECU's next tick; a refused
value changes nothing. `Calibrator.apply(tree)` is the one way a new calibration reaches the
functions, for an XCP write and for a timed set (`RunConfig.calibrations`) alike, so the two
give the same run.

The node's functions list the subtrees they take live (`calibrations()`, beside `dids()` and
`variables()`: a new entry = a subtree whose users can take a new value mid-run); `live()`
collects them. Every other leaf is READ_ONLY in the A2L (it shapes objects built at start, e.g.
the estimator's model) and an XCP write to it is refused (ERR_WRITE_PROTECTED).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from vecu import params as ptree
from vecu.ecu.diagnostics import Calibrations
from vecu.ecu.node import EcuNode


def live(node: EcuNode) -> Calibrations:
    """Subtree (under ecu.) -> how the node's function takes its new value, of every function."""
    found: Calibrations = {}
    for fn in node.functions:
        found.update(getattr(fn, "calibrations", dict)())
    return found


def is_live(path: str, subtrees: Iterable[str]) -> bool:
    """Whether the leaf at `path` (under ecu.) is in one of the live subtrees."""
    return any(path == p or path.startswith(p + ".") for p in subtrees)


class Calibrator:
    """The node's calibration (the ecu subtree) and its changes mid-run."""

    def __init__(self, node: EcuNode, ecu_tree: Any,
                 validate: Callable[[Any], None] | None = None) -> None:
        """validate(ecu_tree) raises ParamError for a tree the run cannot take (the harness
        passes config.validate_tree on the whole tree)."""
        self.node = node
        self.tree = ecu_tree
        self._validate = validate
        self.live = live(node)
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
        for prefix, take in self.live.items():
            new = ptree.get(tree, prefix)
            if new != ptree.get(self.tree, prefix):
                take(new)
        for leaf in ptree.differences(tree, self.tree):
            self.changes.append((t_ns, leaf.path, leaf.value))
        self.tree = tree

    def is_live(self, path: str) -> bool:
        """Whether the running ECU takes the leaf at `path` (under ecu.)."""
        return is_live(path, self.live)

    def set(self, sets: list[tuple[str, Any]], t_ns: int) -> None:
        """check() then apply(): a timed set; ParamError for a refused value."""
        self.apply(self.check(sets), t_ns)
