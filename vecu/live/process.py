"""What `vecu plant` and `vecu ecu` share as separate live processes.

A LiveProcess owns the node's bus (wrapped in a LiveBus), an optional trace recorder on a second
bus of the same channel, a WallClock + Scheduler, SIGINT/SIGTERM handling (a stop flag the
scheduler loop sees within one task), a status panel on stderr when it is a terminal, and the
summary JSON. Every exit path flushes and closes the log and shuts the buses down.
"""

from __future__ import annotations

import ctypes
import json
import logging
import resource
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import can

from vecu.bus import Key, open_bus, receive_filters
from vecu.clock import (
    NS_PER_MS,
    NS_PER_S,
    WallClock,
    perf_ns,
    perf_s,
    process_s,
    wall_time,
)
from vecu.codec import DbcCodec
from vecu.live.livebus import (
    ARRIVAL_TIMESTAMP_INTERFACES,
    SOCKET_INTERFACES,
    FrameLatency,
    LiveBus,
    enlarge_receive_buffer,
    sent_ids,
)
from vecu.live.options import LiveOptions, bus_config
from vecu.recorder import Recorder
from vecu.scheduler import Scheduler, TaskStats
from vecu.stats import DurationHistogram

PRIO_STOP_CHECK, PRIO_STATUS = 40, 50
STOP_CHECK_NS = 10 * NS_PER_MS
STATUS_NS = 500 * NS_PER_MS
FOREVER_NS = 10 * 365 * 24 * 3600 * NS_PER_S


log = logging.getLogger(__name__)
PR_SET_TIMERSLACK = 29
TIMER_SLACK_NS = 1_000


def tighten_timer_slack(slack_ns: int = TIMER_SLACK_NS) -> bool:
    """Ask Linux to wake this process's sleeps within slack_ns of their deadline (the default
    slack is 50 us): the 1 ms tick then needs a shorter busy-wait before each deadline (less CPU
    taken from the other processes of a small machine). False where it is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(PR_SET_TIMERSLACK, slack_ns, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


class StopFlag:
    """Set by SIGINT / SIGTERM; calls the registered stop callbacks (Scheduler.stop)."""

    def __init__(self) -> None:
        self.signal_name: str | None = None
        self._callbacks: list[Callable[[], None]] = []

    @property
    def is_set(self) -> bool:
        return self.signal_name is not None

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)

    def on_stop(self, fn: Callable[[], None]) -> None:
        self._callbacks.append(fn)

    def _handle(self, signum: int, frame: Any) -> None:
        self.signal_name = signal.Signals(signum).name
        for fn in self._callbacks:
            fn()


class TickMeter:
    """Wraps a periodic task: lateness (start - release) and execution time per release."""

    def __init__(self, clock: WallClock, name: str) -> None:
        self.clock = clock
        self.name = name
        self.lateness = DurationHistogram()
        self.exec_time = DurationHistogram()
        self.stats: TaskStats | None = None  # the scheduler's counters, set after scheduling

    def wrap(self, fn: Callable[[int], None]) -> Callable[[int], None]:
        now = self.clock.now_ns
        late, run = self.lateness.record, self.exec_time.record

        def timed(t_ns: int) -> None:
            start = now()
            late(start - t_ns)
            fn(t_ns)
            run(now() - start)

        return timed

    def summary(self) -> dict[str, Any]:
        st = self.stats
        released = (st.runs + st.skipped) if st else 0
        return {
            "releases": released,
            "runs": st.runs if st else 0,
            "overruns": st.overruns if st else 0,
            "skipped": st.skipped if st else 0,
            # releases run late after a stall instead of skipped (a catch-up window)
            "caught_up": st.caught_up if st else 0,
            "max_lateness_us": round(st.max_lateness_ns / 1000, 1) if st else 0.0,
            "overrun_pct": round(100.0 * st.overruns / released, 4) if released else None,
            "jitter_us": self.lateness.summary(),
            "exec_us": self.exec_time.summary(),
        }


class LiveProcess:
    """One node in its own process: bus, recorder, clock, scheduler, signals, status, summary."""

    def __init__(self, opts: LiveOptions, codec: DbcCodec, dbc_node: str,
                 latency: tuple[str, str] | None = None,
                 own_ids: set[Key] | None = None) -> None:
        """own_ids: the CAN IDs this node sends (its echoes dropped), when the DBC does not
        name them (the gateway's diagnostic requests); default: what the DBC gives dbc_node."""
        self.opts = opts
        self.codec = codec
        self.stop = StopFlag()
        self.stop.install()  # first: a signal during set-up must still end in a clean exit
        self.timer_slack = tighten_timer_slack()
        self.clock = WallClock(spin_ns=opts.spin_us * 1000)
        self.sched = Scheduler(self.clock)
        self.stop.on_stop(self.sched.stop)
        cfg = bus_config(opts)
        self.interface = str(cfg["interface"])
        self.channel = str(cfg["channel"])
        self.recorder: Recorder | None = None
        self._buses: list[Any] = []
        self.meters: list[TickMeter] = []
        self.status_lines: Callable[[], list[str]] = list
        self.start_epoch_s: float | None = None
        self.elapsed_s = 0.0
        self.cpu_s = 0.0  # CPU seconds (user + system) of the run itself, set-up excluded
        self._closed = False
        self.rx_filter: list[Key] | None = None
        self.realtime: Any = None  # vecu.live.realtime.RealtimeResult, once run() starts
        bus_args = {k: v for k, v in cfg.items() if k != "interface"}
        try:  # a bad log file or bus: what is already open is shut again (one-line error)
            if opts.log_path:  # its own bus, like candump: sees the other nodes and this one
                rec_bus = open_bus(cfg["interface"], **bus_args)
                self._buses.append(rec_bus)
                if self.interface in SOCKET_INTERFACES:
                    enlarge_receive_buffer(rec_bus, opts.rx_buffer_bytes)
                self.recorder = Recorder(rec_bus, opts.log_path)
            raw = open_bus(cfg["interface"], **bus_args)
            self._buses.append(raw)
        except BaseException:
            self.close()
            raise
        lat = None
        if latency is not None:
            trig, resp = codec[latency[0]], codec[latency[1]]
            lat = FrameLatency((trig.frame_id, trig.is_extended), (resp.frame_id, resp.is_extended),
                               self.interface in ARRIVAL_TIMESTAMP_INTERFACES)
        self.bus = LiveBus(raw, sent_ids(codec, dbc_node) if own_ids is None else own_ids,
                           self.interface, lat,
                           rcvbuf_bytes=opts.rx_buffer_bytes)

    # ----------------------------------------------------------------- setup
    def consume_only(self, keys: set[Key] | frozenset[Key]) -> None:
        """With --rx-filter: the node's bus passes only these (ID, extended) keys (python-can
        filters: in the kernel on SocketCAN, so other traffic costs this process nothing; error
        frames still arrive). Without it: every frame arrives and the node counts what it does
        not consume."""
        if self.opts.rx_filter:
            self.bus.bus.set_filters(receive_filters(keys))
            self.rx_filter = sorted(keys)

    def meter(self, name: str) -> TickMeter:
        m = TickMeter(self.clock, name)
        self.meters.append(m)
        return m

    def signal_ready(self) -> None:
        if self.opts.ready_file:
            Path(self.opts.ready_file).write_text(f"{wall_time():.6f}\n")

    # ------------------------------------------------------------------- run
    def run(self, start_at_perf_ns: int | None = None) -> None:
        """Pace the scheduler on the wall clock until the duration ends or a signal arrives.

        start_at_perf_ns: when given, t = 0 falls on that perf_counter_ns instant (the ECU uses
        it to put its 1 ms grid just after the sensor frames' arrival)."""
        sched = self.sched
        sched.every(STOP_CHECK_NS, self._check_stop, name="stop-check", priority=PRIO_STOP_CHECK)
        if self.recorder is not None:
            from vecu.assembly import PRIO_RECORD, TICK_NS
            sched.every(TICK_NS, self.recorder.drain, name="recorder", priority=PRIO_RECORD)
        show = self.opts.status if self.opts.status is not None else sys.stderr.isatty()
        panel = StatusPanel(self, sys.stderr) if show else None
        if panel is not None:
            sched.every(STATUS_NS, panel.draw, name="status", offset_ns=STATUS_NS,
                        priority=PRIO_STATUS)
        if self.stop.is_set:
            return
        if start_at_perf_ns is not None:
            waiter = WallClock(spin_ns=self.opts.spin_us * 1000)
            waiter.start()
            waiter.wait_until(max(0, start_at_perf_ns - perf_ns()))
        end_ns = (FOREVER_NS if self.opts.duration_s is None
                  else round(self.opts.duration_s * NS_PER_S))
        from vecu.live.realtime import apply_realtime

        self.realtime = apply_realtime(self.opts.realtime, self.opts.cpu)
        for note in self.realtime.notes:
            log.warning("vecu %s: %s", self.opts.role, note)
        self.clock.start()
        self.start_epoch_s = wall_time()
        wall0, cpu0 = perf_s(), process_s()
        try:
            sched.run_until(end_ns)
        finally:
            self.elapsed_s = perf_s() - wall0
            self.cpu_s = process_s() - cpu0
            if panel is not None:
                panel.finish()

    def _check_stop(self, t_ns: int) -> None:
        if self.stop.is_set:  # a signal that came before run_until cleared the scheduler's flag
            self.sched.stop()

    # --------------------------------------------------------------- summary
    def summary(self, extra: dict[str, Any]) -> dict[str, Any]:
        rec = self.recorder
        if rec is not None and not self._closed:
            rec.drain()  # what is still queued belongs to the run
        return {
            "role": self.opts.role,
            "interface": self.interface,
            "channel": self.channel,
            "duration_s": self.opts.duration_s,
            "elapsed_s": round(self.elapsed_s, 3),
            # CPU the run used (busy-wait before each deadline included): % of one core
            "cpu_s": round(self.cpu_s, 3),
            "cpu_pct": round(100.0 * self.cpu_s / self.elapsed_s, 1) if self.elapsed_s else None,
            "stopped_by": self.stop.signal_name or "duration",
            "start_epoch_s": self.start_epoch_s,
            "ticks": {m.name: m.summary() for m in self.meters},
            "tasks": {t.name: {"runs": t.runs, "overruns": t.overruns, "skipped": t.skipped,
                               "max_lateness_us": round(t.max_lateness_ns / 1000, 1)}
                      for t in self.sched.stats},
            "bus": {**self.bus.counts(self.codec),
                    "fd": bool(getattr(self.bus.bus, "protocol", None) == can.CanProtocol.CAN_FD),
                    "rx_filter": None if self.rx_filter is None
                    else [f"0x{i:X}" for i, _ in self.rx_filter]},
            "log": None if rec is None else {"path": rec.path, "frames": rec.frames},
            "peak_rss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
            "realtime": None if self.realtime is None else self.realtime.as_dict(),
            **extra,
        }

    @staticmethod
    def end(summary: dict[str, Any] | None) -> int:
        """A node's exit code once its summary is written and printed: 0; after Ctrl-C (SIGINT)
        an Interrupted (the command line's one line, exit 130). SIGTERM, the way scripts and
        services stop a node, stays 0."""
        if summary is not None and summary.get("stopped_by") == "SIGINT":
            from vecu.errors import Interrupted

            raise Interrupted(f"{summary['elapsed_s']:.1f} s")
        return 0

    def write_summary(self, summary: dict[str, Any]) -> None:
        if self.opts.summary_path:
            Path(self.opts.summary_path).write_text(json.dumps(summary, indent=2) + "\n")

    def close(self) -> None:
        """Flush and close the log, shut the buses down; safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.recorder is not None:
                try:
                    self.recorder.drain()
                finally:
                    self.recorder.close()
        finally:
            for bus in self._buses:
                bus.shutdown()


class StatusPanel:
    """A few lines on stderr, redrawn in place every STATUS_NS: rates, overruns, errors."""

    def __init__(self, proc: LiveProcess, stream: TextIO) -> None:
        self.proc = proc
        self.stream = stream
        self._lines = 0
        self._last_t = 0
        self._last_rx = 0
        self._last_tx = 0
        self._last_runs: dict[str, int] = {}

    def render(self, t_ns: int) -> list[str]:
        p = self.proc
        dt = max(t_ns - self._last_t, 1) / NS_PER_S
        bus = p.bus
        tx = sum(bus.tx_by_id.values())
        head = f"vecu {p.opts.role}  {p.interface} {p.channel}  t = {t_ns / NS_PER_S:8.1f} s"
        lines = [head + "   (Ctrl-C stops)"]
        for m in p.meters:
            st = m.stats
            runs = st.runs if st else 0
            rate = (runs - self._last_runs.get(m.name, 0)) / dt
            self._last_runs[m.name] = runs
            j = m.lateness
            lines.append(f"  {m.name:<6} {rate:7.0f}/s  overruns {st.overruns if st else 0:<6}"
                         f" skipped {st.skipped if st else 0:<6} late "
                         f"{st.caught_up if st else 0:<6} jitter p50 "
                         f"{j.percentile_us(0.5) or 0:6.0f}  p99 {j.percentile_us(0.99) or 0:6.0f}"
                         f"  max {j.max_ns / 1000:7.0f} us")
        lines.append(f"  rx {(bus.received - self._last_rx) / dt:7.0f} frames/s  own echo "
                     f"{bus.own_echo:<8} foreign on own IDs {bus.foreign_own_id:<5} rx errors "
                     f"{bus.rx_errors:<5} error frames {bus.error_frames:<5} tx "
                     f"{(tx - self._last_tx) / dt:7.0f} frames/s")
        if bus.latency is not None:
            h = bus.latency.hist
            lines.append(f"  frame-in -> estimate-out p50 {h.percentile_us(0.5) or 0:6.0f}  p99 "
                         f"{h.percentile_us(0.99) or 0:6.0f}  max {h.max_ns / 1000:7.0f} us")
        lines.extend(p.status_lines())
        self._last_t, self._last_rx, self._last_tx = t_ns, bus.received, tx
        return lines

    def draw(self, t_ns: int) -> None:
        lines = self.render(t_ns)
        out = f"\x1b[{self._lines}F" if self._lines else ""
        out += "".join(f"{line}\x1b[K\n" for line in lines)
        self.stream.write(out)
        self.stream.flush()
        self._lines = len(lines)

    def finish(self) -> None:
        self.stream.flush()
