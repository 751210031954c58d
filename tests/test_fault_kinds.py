"""The fault kinds' records (vecu.fault_kinds.FaultKind) against the DBC: FI_Kind names each
fault kind by its code, and the fault kinds and the restbus disturbances (vecu.restbus.disturb)
split FI_EvKind's code space without overlap, each code named in the DBC (cantools reads it)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cantools
import numpy as np
import pytest

from vecu.codec import builtin_dbc_path
from vecu.errors import BadArgumentError
from vecu.fault_kinds import E2E_KINDS, FRAME_KINDS, FaultKind, make_fault
from vecu.restbus.disturb import KINDS as RESTBUS_KINDS
from vecu.uds.diag_faults.catalogue import BY_CODE, DIAG_EV_KIND

DB = cantools.database.load_file(str(builtin_dbc_path()))


def choices(message: str, signal: str) -> dict[int, str]:
    sig = DB.get_message_by_name(message).get_signal_by_name(signal)
    return {int(code): str(name) for code, name in sig.choices.items()}


def test_fi_kind_names_every_fault_kind_by_its_code():
    assert choices("FI_Command", "FI_Kind") == {int(k): k.label for k in FaultKind}


def test_fault_and_restbus_kinds_split_fi_evkind_without_overlap():
    ev = DB.get_message_by_name("FI_Event").get_signal_by_name("FI_EvKind")
    faults = {int(k): k.label for k in FaultKind}
    restbus = {k.code: name for name, k in RESTBUS_KINDS.items()}
    assert len(restbus) == len(RESTBUS_KINDS)  # no two disturbances share a code
    assert not set(faults) & set(restbus), sorted(set(faults) & set(restbus))
    assert all(0 <= code < 1 << ev.length for code in (*faults, *restbus))
    # the DBC's tables: FI_EvKind is both (a restbus kind by its VAL_ name, e.g. rb_delay for
    # delay), RB_Kind the restbus kinds
    names = choices("FI_Event", "FI_EvKind")
    # the diagnostic faults (vecu.conformance) share one code, their own code in FI_EvSignal
    assert names.pop(DIAG_EV_KIND) == "diag" and DIAG_EV_KIND not in {*faults, *restbus}
    assert set(names) == set(faults) | set(restbus)
    assert {c: names[c] for c in faults} == faults
    assert choices("RB_Command", "RB_Kind") == {c: names[c] for c in restbus}
    for code, name in restbus.items():
        assert names[code] in (name, f"rb_{name}"), (code, name, names[code])


def test_each_record_is_consistent():
    for kind in FaultKind:
        spec = kind.spec
        assert spec.code == int(kind)
        lo, hi = spec.bounds
        assert lo <= spec.default <= hi and not (spec.open_low and spec.default == lo), kind
        assert (spec.law is not None) or (spec.frames is not None) or kind == FaultKind.CLEAR
        assert not spec.e2e or kind in FRAME_KINDS
        assert kind.checked(None) == spec.default
        if spec.default or math.isfinite(lo) or math.isfinite(hi):
            assert spec.meaning, kind  # a value a user gives: say what it means
    assert E2E_KINDS == {FaultKind.WRONG_COUNTER, FaultKind.BAD_CRC}


@pytest.mark.parametrize("kind", [k for k in FaultKind if k.spec.bounds[1] < math.inf])
def test_a_value_above_the_bound_is_refused_by_name(kind):
    with pytest.raises(BadArgumentError, match=f"^{kind.label} fault: .* must be in"):
        kind.checked(kind.spec.bounds[1] * 2 + 1)


def test_only_signal_kinds_build_a_signal_fault():
    rng = np.random.default_rng(0)
    for kind in FaultKind:
        if kind.spec.law is None:
            with pytest.raises(ValueError, match="no signal fault"):
                make_fault(kind, None, rng)
        else:
            assert make_fault(kind, None, rng).kind is kind


def test_the_fault_library_table_in_the_docs_is_the_records():
    """docs/scenarios.md's fault library: one row per kind, its default (in parentheses) the
    record's, '–' for a kind whose value means nothing."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "scenarios.md").read_text()
    rows = dict(re.findall(r"^\| `([a-z_]+)` \| ([^|]*) \|", text, flags=re.MULTILINE))
    for kind in FaultKind:
        if kind == FaultKind.CLEAR:
            continue
        assert kind.label in rows, kind.label
        shown = re.search(r"\(([-0-9.e]+)\)", rows[kind.label])
        if shown is None:
            assert rows[kind.label].strip() == "–" and not kind.spec.meaning or \
                kind == FaultKind.SHORT_SUPPLY, (kind.label, rows[kind.label])
        else:
            assert float(shown.group(1)) == kind.default, (kind.label, rows[kind.label])


def test_diagnostic_fault_codes_fit_fi_evsignal():
    sig = DB.get_message_by_name("FI_Event").get_signal_by_name("FI_EvSignal")
    assert all(0 < code < 1 << sig.length for code in BY_CODE)
