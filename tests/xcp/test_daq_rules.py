"""XCP 1.5 rules the slave keeps, with pyxcp as the master where it can say it and raw frames
where it cannot: a running or selected DAQ list keeps its layout (ERR_DAQ_ACTIVE), CLEAR_DAQ_LIST
stops the list (GET_STATUS follows), ALLOC_ODT_ENTRY again on an ODT replaces its entries,
one answer per refused master block (pyxcp stays in step), DOWNLOAD_NEXT's ERR_SEQUENCE with
the expected count, a CONNECT without its mode byte."""

from __future__ import annotations

import struct

from pyxcp.types import XcpResponseError

from tests.xcp.sim import RawMaster, XcpSim, master_config
from vecu.config import RunConfig
from vecu.xcp.memory import CAL_BASE

DEB = "throttle.tps_monitor.plaus_debounce"


def refused(fn, *args) -> str:
    try:
        fn(*args)
    except XcpResponseError as exc:
        return str(exc.get_error_code())
    return "accepted"


def _addr(sim: XcpSim, name: str) -> int:
    return next(m for m in sim.xcp.measurements if m.name == name).address


def test_a_running_or_selected_list_keeps_its_layout_and_clear_stops_it():
    sim = XcpSim()
    est, status = _addr(sim, "throttle.estimate_deg"), _addr(sim, "monitor.tps.status")
    try:
        def work(m):
            m.connect()
            m.freeDaq()
            m.allocDaq(2)
            m.allocOdt(0, 1)
            m.allocOdt(1, 1)
            m.allocOdtEntry(0, 0, 1)
            m.allocOdtEntry(1, 0, 1)
            m.setDaqPtr(1, 0, 0)
            m.writeDaq(0xFF, 1, 0, status)
            m.setDaqListMode(0x00, 0, 0, 1, 0)
            m.setDaqListMode(0x00, 1, 2, 1, 0)
            m.setDaqPtr(0, 0, 0)
            m.writeDaq(0xFF, 4, 0, est)
            m.setDaqPtr(0, 0, 0)  # the pointer stays on list 0 while it starts
            m.startStopDaqList(1, 0)  # list 0 running
            running = {
                "write_daq": refused(m.writeDaq, 0xFF, 1, 0, status),
                "set_daq_ptr": refused(m.setDaqPtr, 0, 0, 0),
                "alloc_odt_entry": refused(m.allocOdtEntry, 0, 0, 2),
                "set_daq_list_mode": refused(m.setDaqListMode, 0x00, 0, 1, 1, 0),
                "alloc_odt": refused(m.allocOdt, 1, 1),  # after ALLOC_ODT_ENTRY: sequence
            }
            m.startStopDaqList(2, 1)  # list 1 selected
            selected = {
                "set_daq_ptr": refused(m.setDaqPtr, 1, 0, 0),
                "alloc_odt_entry": refused(m.allocOdtEntry, 1, 0, 2),
                "set_daq_list_mode": refused(m.setDaqListMode, 0x00, 1, 0, 1, 0),
            }
            before = m.getStatus().sessionStatus.daqRunning
            m.clearDaqList(0)
            sent = sim.xcp.daq.stats.odts_sent
            time_ms = sim.t_ns
            while sim.t_ns < time_ms + 20_000_000:
                pass
            after = (m.getStatus().sessionStatus.daqRunning,
                     m.getDaqListMode(0).currentMode.running,
                     sim.xcp.daq.stats.odts_sent - sent,
                     m.getDaqListMode(1).currentMode.selected)
            return running, selected, before, after

        running, selected, before, after = sim.serve(work)
    finally:
        sim.close()
    assert running == {"write_daq": "ERR_DAQ_ACTIVE", "set_daq_ptr": "ERR_DAQ_ACTIVE",
                       "alloc_odt_entry": "ERR_DAQ_ACTIVE", "set_daq_list_mode": "ERR_DAQ_ACTIVE",
                       "alloc_odt": "ERR_SEQUENCE"}
    assert selected == {"set_daq_ptr": "ERR_DAQ_ACTIVE", "alloc_odt_entry": "ERR_DAQ_ACTIVE",
                        "set_daq_list_mode": "ERR_DAQ_ACTIVE"}
    # running before CLEAR_DAQ_LIST; after it no list runs, GET_STATUS says so, no DTO leaves
    assert before is True
    assert after == (False, False, 0, True)
    assert sim.xcp.daq.stats.odts_sent > 0


def test_alloc_odt_entry_again_replaces_the_odts_entries_and_their_budget():
    config = RunConfig(duration_s=600.0, kill_tps_at_s=None).with_params(
        [("ecu.xcp.max_odt_entries", "16")])
    sim = XcpSim(config)
    try:
        def work(m):
            m.connect()
            m.freeDaq()
            m.allocDaq(1)
            m.allocOdt(0, 3)
            again = [refused(m.allocOdtEntry, 0, 0, 7) for _ in range(10)]
            second = refused(m.allocOdtEntry, 0, 1, 7)       # 14 of 16
            third = refused(m.allocOdtEntry, 0, 2, 7)        # 21: over
            shrink = refused(m.allocOdtEntry, 0, 0, 2)       # ODT 0 now 2: 9 in use
            third_again = refused(m.allocOdtEntry, 0, 2, 7)  # 16 of 16
            info = m.getDaqListInfo(0)
            # a list of one empty ODT (its DTO: the timestamp) runs before ALLOC_ODT ends:
            # more ODTs would renumber the running list's PIDs
            m.freeDaq()
            m.allocDaq(2)
            m.allocOdt(0, 1)
            m.setDaqListMode(0x10, 0, 0, 1, 0)
            m.startStopDaqList(1, 0)
            odt_running = refused(m.allocOdt, 1, 1)
            m.startStopDaqList(0, 0)
            odt_stopped = refused(m.allocOdt, 1, 1)
            return (again, second, third, shrink, third_again, info.maxOdtEntries, odt_running,
                    odt_stopped)

        (again, second, third, shrink, third_again, max_entries, odt_running,
         odt_stopped) = sim.serve(work)
    finally:
        sim.close()
    assert (odt_running, odt_stopped) == ("ERR_DAQ_ACTIVE", "accepted")
    assert again == ["accepted"] * 10 and second == "accepted"
    assert third == "ERR_MEMORY_OVERFLOW"
    assert shrink == "accepted" and third_again == "accepted" and max_entries == 7


def test_a_refused_block_download_is_one_answer_and_pyxcp_stays_in_step():
    sim = XcpSim()
    # a READ_ONLY vector of 7 or more float64 (a block of DOWNLOAD + DOWNLOAD_NEXTs)
    leaf = next(x for x in sim.xcp.segment.leaves if not x.writable and x.size >= 56)
    deb = sim.xcp.segment.by_path[DEB].address
    try:
        def work(m):
            m.connect()
            m.getCommModeInfo()  # master block mode, MAX_BS
            errors = []
            for _ in range(3):
                errors.append(refused(m.push, leaf.address, 0, bytes(leaf.size)[:48]))
                # each next command gets its own answer, not a stale one of the block
                errors.append(struct.unpack("<i", m.shortUpload(4, deb))[0])
                errors.append(m.getStatus().sessionStatus.daqRunning)
            m.setMta(deb)
            m.download(struct.pack("<i", 40))
            return errors, struct.unpack("<i", m.shortUpload(4, deb))[0]

        errors, deb_after = sim.serve(work)
    finally:
        sim.close()
    assert errors == ["ERR_WRITE_PROTECTED", 300, False] * 3
    assert deb_after == 40
    stats = sim.xcp.proc.stats
    # every DOWNLOAD_NEXT pyxcp sent before it saw the error was dropped without an answer
    assert stats.block_rest_dropped <= 3 * 7 and stats.negative == 3


def test_download_next_errors_carry_the_expected_count_and_a_short_connect_is_mode_0():
    sim = XcpSim()
    deb = sim.xcp.segment.by_path[DEB].address
    ro = next(x for x in sim.xcp.segment.leaves if not x.writable and x.size >= 56)
    try:
        raw = RawMaster(sim)
        out = {"short_connect": raw.ask(bytes([0xFF]))}  # as caringcaribou sends it
        out["stray_next"] = raw.ask(bytes([0xEF, 4, 1, 2, 3, 4]))
        raw.ask(bytes([0xF6, 0, 0, 0]) + struct.pack("<I", deb - 4))
        # a 10-byte block: DOWNLOAD of 6, then DOWNLOAD_NEXT must say 4
        raw.ask(bytes([0xF0, 10]) + bytes(6))
        out["wrong_count"] = raw.ask(bytes([0xEF, 3, 0, 0, 0]))
        # a refused block (READ_ONLY): one answer, its DOWNLOAD_NEXTs dropped unanswered
        raw.ask(bytes([0xF6, 0, 0, 0]) + struct.pack("<I", ro.address))
        out["refused_block"] = raw.ask(bytes([0xF0, 20]) + bytes(6))
        out["rest"] = [raw.ask(bytes([0xEF, n]) + bytes(min(n, 6))) for n in (14, 8, 2)]
        out["after"] = raw.ask(bytes([0xFD]))
        # the rest of a refused block out of order is an error again
        raw.ask(bytes([0xF6, 0, 0, 0]) + struct.pack("<I", ro.address))
        raw.ask(bytes([0xF0, 20]) + bytes(6))
        out["out_of_order"] = raw.ask(bytes([0xEF, 8]) + bytes(6))
        out["bad_mode"] = raw.ask(bytes([0xFF, 0x02]))
        dropped = sim.xcp.proc.stats.block_rest_dropped
    finally:
        sim.close()
    assert out["short_connect"] == [bytes([0xFF, 0x15, 0xC0, 8, 8, 0, 1, 1])]
    assert out["stray_next"] == [bytes([0xFE, 0x29, 0])]      # ERR_SEQUENCE, 0 expected
    assert out["wrong_count"] == [bytes([0xFE, 0x29, 4])]     # ERR_SEQUENCE, 4 expected
    assert out["refused_block"] == [bytes([0xFE, 0x23])]      # ERR_WRITE_PROTECTED
    assert out["rest"] == [[], [], []] and dropped == 3
    assert out["after"] == [bytes([0xFF, 0, 0, 0, 0, 0])]
    assert out["out_of_order"] == [bytes([0xFE, 0x29, 0])]
    assert out["bad_mode"] == [bytes([0xFE, 0x22])]
    assert CAL_BASE <= ro.address


def test_pyxcp_parses_the_expected_count_error():
    """The 3-byte ERR_SEQUENCE packet is still an ERR_SEQUENCE to pyxcp."""
    from pyxcp import types

    assert str(types.XcpError.parse(bytes([0x29, 4]))) == "ERR_SEQUENCE"
    assert master_config() is not None
