"""The 1 kHz control daemon: its loop, states, command handlers, timing and service glue."""
