"""UDS (ISO 14229-1) diagnostics over ISO-TP (ISO 15765-2, can-isotp) for the virtual ECU:
the server (server.py), its DIDs, DTCs and security access, and a tester for scenarios
(tester.py). docs/uds.md."""
