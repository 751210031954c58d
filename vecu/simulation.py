"""The Python entry point: `vecu.simulate(...)` takes what `vecu run` takes, with the same
defaults (the TPS kill at half the duration), and returns the typed run summary
(vecu.summary.RunSummary, frozen dataclasses). `run_config(...)` is the one place both the
command line and simulate() turn those options into a RunConfig (docs/python.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING

from vecu.config import ParamTree, RunConfig
from vecu.errors import BadArgumentError, BadFileError
from vecu.params import ParamError, flatten_toml
from vecu.tomlfile import read_toml

if TYPE_CHECKING:
    from vecu.runner import RunResult
    from vecu.summary import RunSummary

HALF = "half"  # a kill time of half the duration (`--kill-tps-at half`, the default)
Sets = Mapping[str, object] | Iterable[tuple[str, object]]


def run_config(duration_s: float = 10.0, *, seed: int = 0,
               kill_tps_at_s: float | str | None = HALF, fault: str = "dead",
               fault_value: float | None = None, kill_swa_at_s: float | str | None = None,
               swa_fault: str = "dead", swa_fault_value: float | None = None,
               noise_scale: float | None = None, estimator: str | None = None,
               manifold_filter: str | None = None, sets: Sets = (),
               params_file: str | None = None,
               set_at: Iterable[tuple[float, str, object]] = (), realtime: bool = False,
               interface: str | None = None, channel: str | None = None,
               bitrate: int | None = None, log: str | None = None, truth: bool = True,
               keep_series: bool = False, fmu: str | None = None,
               fmu_map: str | None = None) -> RunConfig:
    """The RunConfig of `vecu run` with these options (checked: a UserError on a bad one).
    sets: --set pairs or a {path: value} mapping (after params_file's [set] table); set_at:
    --set-at (at_s, ecu.PATH, value) calibrations; fmu + fmu_map: --fmu / --fmu-map."""
    def at(value: float | str | None) -> float | None:
        return duration_s / 2 if value == HALF else value  # type: ignore[return-value]  # a number or None otherwise

    config = RunConfig(
        duration_s=duration_s, seed=seed, kill_tps_at_s=at(kill_tps_at_s), fault=fault,
        fault_value=fault_value, realtime=realtime, interface=interface, channel=channel,
        bitrate=bitrate, log_path=log, truth=truth, keep_series=keep_series,
        kill_swa_at_s=None if kill_swa_at_s == HALF else at(kill_swa_at_s), swa_fault=swa_fault,
        swa_fault_value=swa_fault_value)
    if (fmu is None) != (fmu_map is None):
        raise BadArgumentError("--fmu and --fmu-map go together (the map binds the FMU to the "
                               "bus; docs/fmu.md)")
    if fmu is not None and fmu_map is not None:
        from vecu.fmu.binding import load_binding

        config = config.with_fmu(load_binding(fmu, fmu_map))
    pairs: list[tuple[str, object]] = []
    if params_file is not None:
        pairs += read_params_file(params_file)
    pairs += list(sets.items()) if isinstance(sets, Mapping) else list(sets)
    config = config.with_params(pairs, noise_scale=noise_scale, estimator=estimator,
                                manifold_filter=manifold_filter)
    timed = tuple(set_at)
    for at_s, path, _ in timed:
        if not path.startswith("ecu.") or not 0 <= at_s < duration_s:
            raise BadArgumentError(f"--set-at {at_s}:{path}: expected S:ecu.PATH=VALUE with 0 "
                                   f"<= S < {duration_s:g} (the run's duration)")
    if timed:
        config = replace(config, calibrations=timed)
    config.validate()
    return config


def read_params_file(path: str, only: str | None = None) -> list[tuple[str, object]]:
    """The (path, value) pairs of a PARAMS.toml: a [set] table of tree paths (dotted keys or
    nested tables, as a scenario's [set]); every pair checked against the tree, a bad one a
    BadFileError naming the file and the key. only: the half of the tree the command takes."""
    doc = read_toml(path)
    extra = sorted(set(doc) - {"set"})
    if extra or not isinstance(doc.get("set"), dict):
        raise BadFileError(path, "expected a [set] table of parameter paths (e.g. "
                           '"ecu.throttle.model.mode3.b" = 0.05)'
                           + (f", not {', '.join(extra)}" if extra else ""))
    pairs = flatten_toml(doc["set"])
    try:
        for key, value in pairs:
            if only is not None and not key.startswith(only):
                raise ParamError(f"this command takes {only}* parameters only")
            ParamTree().set([(key, value)])
    except ParamError as exc:
        raise BadFileError(path, f"[set] key '{key}': {exc}") from None
    return pairs


def simulate(duration_s: float = 10.0, **options: object) -> RunSummary:
    """Run plant + fault injector + ECU as `vecu run` does (keyword options as run_config's)
    and return the typed summary."""
    return simulate_run(duration_s, **options).report


def simulate_run(duration_s: float = 10.0, **options: object) -> RunResult:
    """simulate(), returning the whole RunResult (the summary and, with keep_series=True, each
    function's truth-vs-output series)."""
    from vecu.runner import run

    return run(run_config(duration_s, **options))  # type: ignore[arg-type]  # run_config checks each option
