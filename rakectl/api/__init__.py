"""The command API: its schema, the daemon's socket server, the client and operator commands."""
