"""Configuration: every option declared once, loaded from YAML, rendered as a reference."""
