"""The command line's argument parser: a usage error is one line, raised, not printed."""

from __future__ import annotations

import argparse

from rakectl.errors import ConfigError


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error raises :class:`ConfigError` naming the sub-command (the
    caller prints it as one line after ``rakectl: error:``, exit status 2) instead of
    printing the whole usage and exiting from library code."""

    def error(self, message: str) -> None:  # type: ignore[override]
        command = self.prog.removeprefix("rakectl").strip()  # the CLI prints "rakectl: "
        raise ConfigError(f"{command}: {message}" if command else message)
