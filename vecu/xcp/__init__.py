"""XCP on CAN (ASAM MCD-1 XCP 1.5) for the virtual ECU: a slave that measures and calibrates
the ECU (commands.py, daq.py, transport.py), its memory map of the parameter tree and the
ECU's measurement variables (memory.py, measurements.py), live calibration (calibration.py)
and the A2L (ASAM MCD-2 MC 1.7) that describes it (a2l.py). docs/xcp.md."""
