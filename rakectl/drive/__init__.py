"""The controller's side of the CAN bus: opening it, bringing the drives up, the 1 kHz exchange."""
