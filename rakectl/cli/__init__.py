"""The ``rakectl`` command line."""
