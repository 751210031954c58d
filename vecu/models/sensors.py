"""Sensor transfer laws shared by the plant (which produces the signal) and the ECU (which reads it)."""

from __future__ import annotations

from dataclasses import dataclass

from vecu.kernels import kernel


@kernel(small=True)
def tps_law(v_at_0: float, v_at_90: float, theta_deg: float) -> float:
    """The TPS's linear angle-to-voltage law (TpsCalibration.voltage; the plant's compiled ticks)."""
    return v_at_0 + (v_at_90 - v_at_0) * theta_deg / 90.0


@dataclass(frozen=True)
class TpsCalibration:
    """Throttle position sensor: linear angle-to-voltage law, 0.5 V at 0 deg and 4.5 V at 90 deg,
    readings outside [fault_low_v, fault_high_v] electrical faults (docs/models.md, "TPS transfer
    law"); v_at_0=0, v_at_90=5 restores the paper's 0-5 V law."""

    v_at_0: float = 0.5
    v_at_90: float = 4.5
    fault_low_v: float = 0.25
    fault_high_v: float = 4.75

    def voltage(self, theta_deg: float) -> float:
        return tps_law(self.v_at_0, self.v_at_90, theta_deg)

    def angle(self, voltage: float) -> float:
        """Voltage -> angle in deg, clipped to the mechanical range [0, 90]."""
        theta = (voltage - self.v_at_0) * 90.0 / (self.v_at_90 - self.v_at_0)
        return 0.0 if theta < 0.0 else (90.0 if theta > 90.0 else theta)  # noqa: FURB136 (NaN passes, as in the kernels)
