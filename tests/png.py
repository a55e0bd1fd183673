"""A PNG's pixel size from its header, for tests of the plots (no image library)."""

from __future__ import annotations

from pathlib import Path

SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) of the PNG at ``path``; AssertionError if it is not one."""
    header = path.read_bytes()[:24]
    assert header[:8] == SIGNATURE and header[12:16] == b"IHDR", f"{path} is not a PNG"
    return int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")
