"""Tester conformance: diagnostic faults an ECU or the DoIP gateway commits on purpose (the
catalogue), the engines that commit them, and the bench that judges a tester (docs/conformance.md)."""
