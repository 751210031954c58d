"""The gateway: a DoIP edge node (ISO 13400-2) in front of vecu's CAN ECUs (docs/gateway.md)."""
