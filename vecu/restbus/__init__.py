"""Restbus: the rest of a user's bus simulated from their DBC / ARXML (docs/restbus.md).

spec.py (databases -> message plans, E2E.toml, every check), values.py (start values and
VALUES.toml sources), node.py (the messages on the shared scheduler), disturb.py (disturbance
kinds), commands.py (RB_Command for live disturbances), session.py (a restbus on its own).
"""
