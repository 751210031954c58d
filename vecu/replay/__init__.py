"""Trace record / replay: python-can readers in, the ECU on the scheduler, estimate frames out."""
