"""FmuFunction: an FMU co-simulation slave (FMPy) as an ECU function.

Every communication step (the map's step_ms) the FMU advances from t - step to t
(FMI 2.0 section 4.2.2 fmi2DoStep, FMI 3.0 section 4.2.1 fmi3DoStep) with its inputs set to the
latest validated values of their signals (converted to the FMU's unit); each output message is
sent at its DBC cycle time with the latest outputs (E2E protected when the map's E2E file or the
message's own layout says so). An FMU call that fails (an error status, which FMPy raises, or
any exception) is logged once and turns the function invalid (validity 3, DID 0x060F); its
outputs stop while the ECU runs on. Parameters: the `ecu.fmu.<instance>.*` subtree, set before
initialisation; tunable ones also live (XCP, timed sets: `calibrations()`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import shutil
import weakref
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from functools import partial
from typing import Any

from vecu.clock import NS_PER_MS, NS_PER_S
from vecu.codec import DbcCodec
from vecu.ecu.diagnostics import FLOAT, UBYTE, Calibrations, Did, Variable, validity_did
from vecu.ecu.node import Send, Subscription
from vecu.ecu.validity import INIT, INVALID, VALID
from vecu.fmu.binding import FmuBinding, FmuVariable, SignalLink, _fmpy

log = logging.getLogger(__name__)

# FMI 3.0 setter / getter by type (section 3.2.3); FMI 2.0 has Real, Integer, Boolean
_FMI3 = {"Float64": "Float64", "Float32": "Float32", "Int8": "Int8", "UInt8": "UInt8",
         "Int16": "Int16", "UInt16": "UInt16", "Int32": "Int32", "UInt32": "UInt32",
         "Int64": "Int64", "UInt64": "UInt64", "Enumeration": "Int64", "Boolean": "Boolean"}
_FMI2 = {"Real": "Real", "Integer": "Integer", "Enumeration": "Integer", "Boolean": "Boolean"}
VALIDITY_DID, OUTPUT_DIDS, PARAMETER_DIDS = 0x060F, 0x0600, 0x0610
DID_PARAMETER_SCALE = 1e-6


def _accessor(fmu: Any, version: str, var: FmuVariable, verb: str) -> Callable[..., Any]:
    kind = (_FMI3 if version == "3.0" else _FMI2)[var.fmi_type]
    call = getattr(fmu, f"{verb}{kind}")
    vrs = [var.vr]
    if verb == "get":
        return lambda: call(vrs)[0]
    return lambda value: call(vrs, [value])


@dataclass(frozen=True)
class FmuSummary:
    """The FMU function's section of the run summary."""

    fmu: str
    instance: str
    steps: int
    frames_sent: int
    errors: int
    first_error: str | None
    valid_at_end: bool

    def lines(self) -> list[str]:
        state = "valid" if self.valid_at_end else f"INVALID ({self.first_error})"
        return [(f"fmu {self.instance}: {self.steps} steps, {self.frames_sent} frames sent, "
                f"{self.errors} errors, {state}")]


class FmuFunction:
    """The FMU on the ECU's tick: inputs from subscriptions, doStep, outputs on their cycles."""

    name = "fmu"
    timeouts = 0

    def __init__(self, binding: FmuBinding, values: Any, codec: DbcCodec) -> None:
        fmpy = _fmpy()
        from fmpy import instantiate_fmu, read_model_description

        self.binding = b = binding
        self._step_ns = b.step_ms * NS_PER_MS
        self._out = {m: codec[m] for m in dict.fromkeys(link.message for link in b.outputs)}
        cycles = [round(fc.cycle_time_ms or 0) for fc in self._out.values()]
        self.period_ns = math.gcd(b.step_ms, *cycles) * NS_PER_MS
        self._cycles = {m: round(fc.cycle_time_ms or 0) * NS_PER_MS for m, fc in self._out.items()}
        self._protect = {m: (p, p.protector()) for m, p in b.e2e.items()}
        self._counters = dict.fromkeys(b.e2e, 0)
        self.validity = INIT
        self.steps = self.frames_sent = self.errors = 0
        self.first_error: str | None = None
        self._values = values
        self.outputs: dict[str, Any] = {}  # variable name -> latest value (FMU unit)
        self._unzipped = fmpy.extract(b.fmu)
        weakref.finalize(self, shutil.rmtree, self._unzipped, True)
        md = read_model_description(b.fmu)
        self._fmu = instantiate_fmu(self._unzipped, md, fmi_type="CoSimulation")
        fmu = self._fmu
        self._alive = [True]  # False once a call failed: the slave is freed, not terminated
        weakref.finalize(self, _release, fmu, self._alive)
        self._set = {v.name: _accessor(fmu, b.fmi_version, v, "set")
                     for v in (*b.parameters, *(link.variable for link in b.inputs))}
        self._get = {link.variable.name: _accessor(fmu, b.fmi_version, link.variable, "get")
                     for link in b.outputs}
        self._inputs_of: dict[str, list[SignalLink]] = {}
        for link in b.inputs:
            self._inputs_of.setdefault(link.message, []).append(link)
        self._pending: dict[str, Any] = {}  # input variable -> value to set before the step
        self._guard(self._initialise)

    def _initialise(self) -> None:
        fmu = self._fmu
        if self.binding.fmi_version == "2.0":
            fmu.setupExperiment(startTime=0.0)
        for f in fields(self._values):  # parameters before initialisation (FMI 2.0 4.2.4)
            self._set[f.name](getattr(self._values, f.name))
        if self.binding.fmi_version == "2.0":
            fmu.enterInitializationMode()
        else:
            fmu.enterInitializationMode(startTime=0.0)
        fmu.exitInitializationMode()
        self._read_outputs()

    def _guard(self, call: Callable[[], None]) -> bool:
        """call(); False (and the function invalid) when the FMU fails."""
        if self.validity == INVALID:
            return False
        try:
            call()
        except Exception as exc:  # noqa: BLE001 - an FMU's error status (FMPy raises) or crash
            self.errors += 1
            self.validity = INVALID
            self._alive[0] = False
            self.first_error = f"{type(exc).__name__}: {exc}".splitlines()[0]
            log.error("fmu %s: %s; the function is invalid from now on, the ECU runs on",
                      self.binding.name, self.first_error)
            return False
        return True

    def _read_outputs(self) -> None:
        for name, get in self._get.items():
            self.outputs[name] = get()

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(m, partial(self._on_values, links))
                for m, links in self._inputs_of.items()]

    def _on_values(self, links: list[SignalLink], values: dict[str, float], t_ns: int) -> None:
        for link in links:
            x = values[link.signal] * link.scale + link.offset
            kind = link.variable.kind
            self._pending[link.variable.name] = (
                x if kind == "float" else bool(round(x)) if kind == "bool" else int(round(x)))

    def _step(self, t_ns: int) -> None:
        for name, value in self._pending.items():
            self._set[name](value)
        self._pending.clear()
        self._fmu.doStep((t_ns - self._step_ns) / NS_PER_S, self._step_ns / NS_PER_S)
        self._read_outputs()
        self.steps += 1
        self.validity = VALID

    def run(self, t_ns: int, send: Send) -> None:
        if t_ns % self._step_ns == 0 and t_ns > 0:
            self._guard(lambda: self._step(t_ns))
        if self.validity == INVALID:
            return
        for msg, fc in self._out.items():
            if t_ns % self._cycles[msg]:
                continue
            values = dict(fc.start_values)
            for link in self.binding.outputs:
                if link.message == msg and self.outputs.get(link.variable.name) is not None:
                    values[link.signal] = (float(self.outputs[link.variable.name]) * link.scale
                                           + link.offset)
            frame = fc.frame(values, t_ns / NS_PER_S)
            if msg in self._protect:
                prot, protect = self._protect[msg]
                buf = bytearray(frame.data)
                prot.set_counter(buf, self._counters[msg] % prot.counter_modulo)
                protect(buf)
                self._counters[msg] += 1
                frame.data = buf
            self.frames_sent += send(frame)

    @property
    def estimates_sent(self) -> int:
        """Its frames sent (a replay's per-function count)."""
        return self.frames_sent

    def status_signals(self) -> dict[str, int]:
        return {}

    def dids(self) -> list[Did]:
        """UDS: validity (0x060F), the outputs (0x0600 + i, in their signal's scale) and the
        parameters (0x0610 + i, micro-units)."""
        out = [validity_did(VALIDITY_DID, f"fmu {self.binding.name} validity",
                            lambda: self.validity)]
        for i, link in enumerate(self.binding.outputs[:15]):
            sig = self._out[link.message].signal(link.signal)
            out.append(Did(OUTPUT_DIDS + i, f"fmu output {link.variable.name}", "i",
                           float(sig.scale) / (link.scale or 1.0), link.variable.unit,
                           partial(self._output, link.variable.name)))
        for i, p in enumerate(self.binding.parameters[:15]):
            out.append(Did(PARAMETER_DIDS + i, f"fmu parameter {p.name}", "i",
                           DID_PARAMETER_SCALE, p.unit,
                           partial(self._parameter, p.name)))
        return out

    def variables(self) -> list[Variable]:
        """XCP measurements: each bound output and the validity."""
        name = self.binding.name
        out = [Variable(f"fmu.{name}.validity", "", UBYTE, lambda: self.validity, 0, 3,
                        f"FMU {name} validity (0 init, 1 valid, 3 invalid)")]
        for link in self.binding.outputs:
            out.append(Variable(f"fmu.{name}.{link.variable.name}", link.variable.unit, FLOAT,
                                partial(self._output, link.variable.name),
                                -1e9, 1e9, f"FMU {name} output {link.variable.name}"))
        return out

    def calibrations(self) -> Calibrations:
        """The tunable parameters, set in the FMU from the next step (FMI 2.0 section 4.2.4)."""
        tunable = {p.name for p in self.binding.parameters if p.tunable}
        return {f"fmu.{self.binding.name}.{n}": partial(self._calibrate, n) for n in tunable}

    def _output(self, name: str) -> float | None:
        return _number(self.outputs.get(name))

    def _parameter(self, name: str) -> float | None:
        return _number(getattr(self._values, name))

    def _calibrate(self, name: str, value: Any) -> None:
        self._values = replace(self._values, **{name: value})
        self._guard(lambda: self._set[name](value))

    def summary(self) -> FmuSummary:
        return FmuSummary(self.binding.fmu, self.binding.name, self.steps, self.frames_sent,
                          self.errors, self.first_error, self.validity != INVALID)


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


def _release(fmu: Any, alive: list[bool]) -> None:
    """Terminate and free the slave (FMI 2.0 section 4.2.4); a failed one is only freed (its
    state allows no fmi2Terminate). An FMU may refuse either: nothing is left to report."""
    with contextlib.suppress(Exception):
        if alive[0]:
            fmu.terminate()
    with contextlib.suppress(Exception):
        fmu.freeInstance()
