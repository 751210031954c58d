"""Live mode: the plant, the ECU and the fault injector as separate processes on a real bus.

stats: fixed-size histograms (memory stays flat however long a process runs);
livebus: the bus as one node sees it (own echoes dropped and counted, frame-in -> estimate-out);
process: wall-clock pacing, signals, warm-up, status panel and summary shared by `vecu plant`
and `vecu ecu`; netns / scenario: multi-process runs over udp_multicast in a private network
namespace (tests and `vecu bench --only live`).
"""
