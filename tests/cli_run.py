"""The rakectl CLI run as an operator runs it: a real process, from the repository's
root, its output captured."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_rakectl(*args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    """``rakectl ARGS…`` to its end (at most ``timeout_s``)."""
    return subprocess.run([sys.executable, "-m", "rakectl", *args], capture_output=True,
                          text=True, timeout=timeout_s, cwd=ROOT)
