"""Tester conformance: the bench that judges a tester against each diagnostic fault (bench,
judge, report) and the gateway's DoIP fault engine (docs/conformance.md). The catalogue, the
settings and the ECU's fault engine are vecu.uds.diag_faults."""
