"""Diagnostic faults the ECU commits on purpose for tester conformance: the catalogue (one
record per named fault with the standard's rule), settings (windows, `@request=N`), and the
engine on the UDS server's path (docs/conformance.md). The DoIP ones are the gateway's
(vecu.conformance.doip_faults); the bench that judges a tester is vecu.conformance."""
