"""`vecu gateway`: a DoIP entity (ISO 13400-2) in front of vecu's CAN ECUs, routing each
diagnostic message by logical address into the ECU's ISO-TP channel (docs/gateway.md)."""
