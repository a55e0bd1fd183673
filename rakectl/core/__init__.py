"""The pure control core: kinematics, models, the impedance law, the clamp, the planners.

Nothing here imports ``can``, ``yaml``, ``structlog`` or ``time``: numbers in,
numbers out, so the daemon, the simulations and the tests run the same code.
"""
