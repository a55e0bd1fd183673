"""Where the example configurations and the systemd files are: the checkout's ``config/``
and ``systemd/``, or, installed from a wheel, the copies it puts in
``<prefix>/share/rakectl/`` (``rakectl files`` prints the directory, or copies it)."""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

from rakectl.errors import ConfigError

CHECKOUT = Path(__file__).resolve().parents[2]
SHARE_NAME = "share/rakectl"


def shared_root() -> Path:
    """The directory holding ``config/`` and ``systemd/``: the checkout when running from
    one, else the wheel's data directory under the interpreter's prefix."""
    if (CHECKOUT / "config").is_dir() and (CHECKOUT / "systemd").is_dir():
        return CHECKOUT
    for prefix in (sysconfig.get_path("data"), sys.prefix, sys.base_prefix):
        candidate = Path(prefix) / SHARE_NAME
        if (candidate / "config").is_dir():
            return candidate
    raise ConfigError("the example configuration is not installed: no config/ next to the "
                      f"package and none under {Path(sys.prefix) / SHARE_NAME}")


def config_dir() -> Path:
    return shared_root() / "config"


def systemd_dir() -> Path:
    return shared_root() / "systemd"
