"""The operator's live view and run recordings in Foxglove's formats (the ``[view]`` extra)."""
