"""The ECU's XCP slave with pyxcp as the master, on the simulated clock: standard commands,
uploads, calibration within bounds from the next tick, every refusal with its error code (the
names are pyxcp's), calibration pages, checksum, seed & key."""

from __future__ import annotations

import math
import struct
import zlib

import pytest
from pyxcp import checksum, types
from pyxcp.types import XcpResponseError

from tests.xcp.sim import XcpSim
from vecu.config import ParamTree, RunConfig
from vecu.xcp.memory import CAL_BASE
from vecu.xcp.security import xcp_key

DEB = "throttle.tps_monitor.plaus_debounce"


@pytest.fixture
def sim():
    s = XcpSim()
    yield s
    s.close()


def refused(fn, *args) -> str:
    """The pyxcp name of the error the slave answered (the test fails if it accepted)."""
    try:
        fn(*args)
    except XcpResponseError as exc:
        return str(exc.get_error_code())
    raise AssertionError(f"{fn.__name__}{args} was accepted")


def read(m, address: int, n: int = 8) -> bytes:
    """SET_MTA + UPLOAD (SHORT_UPLOAD carries 7 bytes at most on CAN)."""
    m.setMta(address)
    return bytes(m.upload(n))


def addr(sim: XcpSim, path: str) -> int:
    return sim.xcp.segment.by_path[path].address


def meas(sim: XcpSim, name: str):
    return next(m for m in sim.xcp.measurements if m.name == name)


def test_connect_status_ids_and_the_a2l_by_upload(sim):
    def work(m):
        m.connect()
        return m.slaveProperties, m.getStatus(), m.identifier(1), m.identifier(4)

    props, status, name, a2l = sim.serve(work)
    assert (props.maxCto, props.maxDto, props.byteOrder) == (8, 8, "INTEL")
    assert props.supportsCalpag and props.supportsDaq and not props.supportsStim
    assert not any(status.resourceProtectionStatus[r] for r in ("calpag", "daq", "pgm"))
    assert name == "vecu"
    assert a2l == sim.xcp.a2l() and a2l.startswith("ASAP2_VERSION 1 71")
    assert "/begin CHARACTERISTIC ecu.throttle.tps_monitor.plaus_debounce" in a2l


def test_uploads_read_the_calibration_and_the_ecu_live(sim):
    sim.run_to(0.5)
    tree = ParamTree().ecu

    def work(m):
        m.connect()
        m.setMta(addr(sim, DEB))
        deb = m.upload(4)
        sigma = read(m, addr(sim, "throttle.tps_monitor.plaus_sigma"))
        leaf = next(x for x in sim.xcp.segment.leaves if len(x.dims) == 1 and x.count > 3)
        m.setMta(leaf.address)
        blk = m.upload(leaf.size)  # slave block mode: several responses
        table = sim.xcp.segment.by_path["manifold.kf.params.cd_table"]
        m.setMta(table.address)
        tbl = m.upload(table.size)
        est = read(m, meas(sim, "throttle.estimate_deg").address, 4)
        status = m.shortUpload(1, meas(sim, "monitor.tps.status").address)
        wheel = read(m, meas(sim, "monitor.wheel.value").address, 4)
        return deb, sigma, leaf, blk, est, status, tbl, wheel

    deb, sigma, leaf, blk, est, status, tbl, wheel = sim.serve(work)
    assert struct.unpack("<i", deb)[0] == tree.throttle.tps_monitor.plaus_debounce == 300
    assert struct.unpack("<d", sigma)[0] == tree.throttle.tps_monitor.plaus_sigma
    from vecu import params as ptree
    assert struct.unpack(f"<{leaf.count}d", blk) == ptree.get(tree, leaf.path)
    rows = tree.manifold.kf.params.cd_table  # a table: row after row
    assert struct.unpack(f"<{len(rows) * len(rows[0])}d", tbl) == tuple(v for r in rows for v in r)
    assert 0.0 <= struct.unpack("<f", wheel)[0] < 300.0  # km/h, as the ECU sees the sensor
    angle = struct.unpack("<f", est)[0]
    assert math.isfinite(angle) and -5.0 < angle < 95.0
    assert status == b"\x00"  # TPS ok


def test_a_download_acts_from_the_next_tick_within_bounds_and_a_refusal_changes_nothing(sim):
    mon = sim.ecu.monitors["tps"]

    def work(m):
        m.connect()
        m.getCommModeInfo()  # MAX_BS for the block downloads (push)
        m.setMta(addr(sim, DEB))
        m.download(struct.pack("<i", 1000))
        errors = {}
        m.setMta(addr(sim, DEB))
        errors["zero"] = refused(m.download, struct.pack("<i", 0))  # below 1
        m.setMta(addr(sim, "throttle.tps_monitor.plaus_sigma"))  # a float in two DOWNLOADs
        nan = struct.pack("<d", math.nan)
        m.download(nan[:6])  # staged: the leaf is not complete yet
        errors["nan"] = refused(m.download, nan[6:])
        m.setMta(addr(sim, "throttle.noise_scale"))
        errors["read_only"] = refused(m.download, b"\x00\x00")
        m.setMta(meas(sim, "throttle.estimate_deg").address)
        errors["measurement"] = refused(m.download, b"\x00\x00")
        # a block broken off by a DOWNLOAD (pyxcp's push of 7..12 bytes does that)
        errors["broken_block"] = refused(m.push, addr(sim, "throttle.tps_monitor.plaus_sigma"),
                                         0, struct.pack("<d", 3.5))
        m.setMta(0x0500_0000)
        errors["unmapped"] = refused(m.upload, 4)
        errors["unknown"] = refused(m.userCmd, 1, b"")
        errors["short_download"] = refused(m.shortDownload, addr(sim, DEB), 0, b"\x01")
        # master block mode: two float64 leaves in one block (DOWNLOAD + 2 DOWNLOAD_NEXT)
        m.push(addr(sim, "throttle.tps_monitor.plaus_sigma"), 0, struct.pack("<dd", 3.0, 20.0))
        # a block with one value out of bounds is refused whole
        errors["block"] = refused(m.push, addr(sim, "throttle.tps_monitor.plaus_sigma"), 0,
                                  struct.pack("<dd", 4.0, -1.0))
        after = m.shortUpload(4, addr(sim, DEB)), read(
            m, addr(sim, "throttle.tps_monitor.plaus_sigma"))
        return errors, after

    errors, (deb, sigma) = sim.serve(work)
    assert errors == {"zero": "ERR_OUT_OF_RANGE", "nan": "ERR_OUT_OF_RANGE",
                      "read_only": "ERR_WRITE_PROTECTED", "measurement": "ERR_WRITE_PROTECTED",
                      "unmapped": "ERR_ACCESS_DENIED", "unknown": "ERR_CMD_UNKNOWN",
                      "short_download": "ERR_OUT_OF_RANGE", "block": "ERR_OUT_OF_RANGE",
                      "broken_block": "ERR_SEQUENCE"}
    assert struct.unpack("<i", deb)[0] == 1000 and struct.unpack("<d", sigma)[0] == 3.0
    assert (mon.cfg.plaus_debounce, mon.cfg.plaus_sigma, mon.cfg.plaus_margin) == (1000, 3.0, 20.0)
    assert sim.xcp.calibrator.tree.throttle.noise_scale == 1.0
    taken = sim.xcp.summary()["calibrations_taken"]
    assert [p for _, p, _ in taken] == ["ecu." + DEB, "ecu.throttle.tps_monitor.plaus_sigma",
                                        "ecu.throttle.tps_monitor.plaus_margin"]
    assert all(round(t * 1000) == t * 1000 for t, _, _ in taken)  # at a tick
    assert sim.xcp.proc.stats.refused_writes == 3


def test_calibration_pages_reference_is_the_defaults(sim):
    mon = sim.ecu.monitors["tps"]
    seen = {}

    def work(m):
        m.connect()
        seen["pages"] = m.getCalPage(0x01, 0), m.getCalPage(0x02, 0)
        m.setMta(addr(sim, DEB))
        m.download(struct.pack("<i", 1000))
        m.setCalPage(0x01, 0, 1)  # the ECU on the reference page
        sim_wait(sim, 3)
        seen["ecu_on_ref"] = mon.cfg.plaus_debounce
        seen["xcp_reads_working"] = m.shortUpload(4, addr(sim, DEB))
        m.setCalPage(0x02, 0, 1)
        seen["xcp_reads_ref"] = m.shortUpload(4, addr(sim, DEB))
        m.setMta(addr(sim, DEB))
        seen["write_ref"] = refused(m.download, struct.pack("<i", 10))
        m.setCalPage(0x83, 0, 0)
        sim_wait(sim, 3)
        seen["back"] = mon.cfg.plaus_debounce
        m.copyCalPage(0, 1, 0, 0)  # working = reference
        sim_wait(sim, 3)
        seen["copied"] = mon.cfg.plaus_debounce, m.shortUpload(4, addr(sim, DEB))
        seen["errors"] = (refused(m.copyCalPage, 0, 0, 0, 1), refused(m.setCalPage, 0x03, 0, 2),
                          refused(m.setCalPage, 0x03, 1, 0), refused(m.getCalPage, 0x04, 0))
        seen["pag"] = m.getPagProcessorInfo()
        seen["segment"] = (m.getSegmentInfo(0, 0, 0, 0), m.getSegmentInfo(0, 0, 1, 0),
                           m.getSegmentInfo(1, 0, 0, 0))
        seen["page_info"] = m.getPageInfo(0, 0), m.getPageInfo(0, 1)
        seen["info_errors"] = (refused(m.getSegmentInfo, 2, 0, 0, 0), refused(m.getPageInfo, 0, 2),
                               refused(m.getPageInfo, 1, 0))
        return seen

    sim.serve(work)
    assert seen["pages"] == (0, 0)
    assert seen["ecu_on_ref"] == 300 and seen["back"] == 1000
    assert struct.unpack("<i", seen["xcp_reads_working"])[0] == 1000
    assert struct.unpack("<i", seen["xcp_reads_ref"])[0] == 300
    assert seen["write_ref"] == "ERR_WRITE_PROTECTED"
    assert seen["copied"] == (300, struct.pack("<i", 300))
    assert seen["errors"] == ("ERR_WRITE_PROTECTED", "ERR_PAGE_NOT_VALID",
                              "ERR_SEGMENT_NOT_VALID", "ERR_MODE_NOT_VALID")
    assert seen["pag"].maxSegments == 1 and not seen["pag"].pagProperties.freezeSupported
    basic_addr, basic_len, standard = seen["segment"]
    assert (basic_addr.basicInfo, basic_len.basicInfo) == (CAL_BASE, sim.xcp.segment.size)
    assert standard.maxPages == 2 and standard.maxMapping == 0
    working, reference = seen["page_info"]
    assert working.properties.xcp_write_access and not reference.properties.xcp_write_access
    assert working.properties.ecu_access and reference.properties.xcp_read_access
    assert seen["info_errors"] == ("ERR_OUT_OF_RANGE", "ERR_PAGE_NOT_VALID",
                                   "ERR_SEGMENT_NOT_VALID")


def sim_wait(sim: XcpSim, ticks: int) -> None:
    """From the master's thread: until the simulated clock has moved `ticks` ms."""
    import time

    end = sim.t_ns + ticks * 1_000_000
    while sim.t_ns < end:
        time.sleep(0.001)


def test_build_checksum_is_xcp_crc_32_of_the_segment(sim):
    size = sim.xcp.segment.size

    def work(m):
        m.connect()
        m.setMta(CAL_BASE)
        image = m.fetch(size)
        m.setMta(CAL_BASE)
        cs = m.buildChecksum(size)
        m.setMta(CAL_BASE)
        errors = refused(m.buildChecksum, 0), refused(m.buildChecksum, size + 8)
        return image, cs, errors

    image, cs, errors = sim.serve(work)
    assert image == bytes(sim.xcp.segment.image(ParamTree().ecu))
    assert cs.checksumType == "XCP_CRC_32"
    assert cs.checksum == checksum.check(image, "XCP_CRC_32") == zlib.crc32(image)
    assert errors == ("ERR_OUT_OF_RANGE", "ERR_ACCESS_DENIED")


def test_seed_and_key_locks_cal_and_daq_until_unlocked():
    config = RunConfig(duration_s=600.0, kill_tps_at_s=None).with_params(
        [("ecu.xcp.seed_key", "true")])
    sim = XcpSim(config)
    secret = config.params.ecu.xcp.secret
    try:
        def wrong(m):
            m.connect()
            locked = m.getCurrentProtectionStatus()
            m.setMta(addr(sim, DEB))
            errs = [refused(m.download, struct.pack("<i", 1000)), refused(m.freeDaq)]
            m.getSeed(types.XcpGetSeedMode.FIRST_PART, 0x01)
            errs.append(refused(m.unlock, 4, b"\x00\x00\x00\x00"))
            return locked, errs

        locked, errs = sim.serve(wrong)
        assert all(locked[r] for r in ("calpag", "daq", "pgm"))
        assert errs == ["ERR_ACCESS_LOCKED"] * 3
        assert not sim.xcp.proc.connected  # a wrong key disconnects

        def right(m):
            m.connect()
            m.cond_unlock("calpag")
            m.setMta(addr(sim, DEB))
            m.download(struct.pack("<i", 1000))
            return m.getCurrentProtectionStatus()

        status = sim.serve(right, seed_n_key_function=lambda res, seed: xcp_key(secret, res, seed))
        assert not status["calpag"] and status["daq"] and status["pgm"]
        assert sim.ecu.monitors["tps"].cfg.plaus_debounce == 1000
    finally:
        sim.close()
