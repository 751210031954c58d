"""The DoIP entity's settings (ISO 13400-2:2019 Table 46 timings, the socket table, routing
activation types), taken from the gateway config's `[doip]` table (vecu.gateway.config)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class DoipSettings:
    """One DoIP entity's behaviour; the defaults are the standard's values."""

    protocol_version: int = 0x02          # of announcements and answers to version 0xFF
    max_sockets: int = 4                  # TCP_DATA sockets with routing active (the table)
    max_data_size: int = 4103             # MDS: header 8 + SA/TA 4 + 4091 bytes of UDS
    memory_bytes: int = 4 * 4103          # payload bytes being received at once (NACK 0x03)
    initial_inactivity_s: float = 2.0     # T_TCP_Initial_Inactivity: connect -> activation
    general_inactivity_s: float = 300.0   # T_TCP_General_Inactivity: silence of an active socket
    alive_check_s: float = 0.5            # T_TCP_Alive_Check
    announce_wait_s: float = 0.5          # A_DoIP_Announce_Wait: random delay 0 .. this
    announce_interval_s: float = 0.5      # A_DoIP_Announce_Interval
    announce_count: int = 3               # A_DoIP_Announce_Num
    announce_address: str | None = None   # None: the broadcast address of the bind address
    activation_types: tuple[int, ...] = (0x00, 0x01)  # default, WWH-OBD
    # activation types that need an authentication (answered 0x04: vecu has none) or a
    # confirmation (answered 0x05: nobody in the vehicle confirms)
    authentication: tuple[int, ...] = ()
    confirmation: tuple[int, ...] = ()
    further_action: int = 0x00            # announcement's "further action required"
    power_mode: int = 0x01                # diagnostic power mode: ready

    def ns(self, seconds: float) -> int:
        return round(seconds * NS_PER_S)

    @property
    def max_payload(self) -> int:
        return self.max_data_size - 8


def settings_of(config: Any) -> DoipSettings:
    """The DoIP settings a GatewayConfig holds (its `[doip]` table)."""
    return DoipSettings(
        protocol_version=config.protocol_version, max_sockets=config.max_sockets,
        initial_inactivity_s=config.initial_inactivity_s,
        general_inactivity_s=config.general_inactivity_s,
        alive_check_s=config.alive_check_timeout_s,
        announce_wait_s=config.announce_max_delay_ms / 1000,
        announce_interval_s=config.announce_interval_ms / 1000,
        announce_count=config.announce_count, further_action=config.further_action,
        power_mode=config.power_mode, activation_types=tuple(config.activation_types),
        authentication=tuple(config.authentication_types),
        confirmation=tuple(config.confirmation_types))
