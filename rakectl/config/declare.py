"""How a configuration option is declared: once, with its type, default, unit, bounds, doc.

An option is a field of a frozen dataclass declared with :func:`setting`: its
annotation is the type, and the metadata carries the default, the unit, the
bounds and the documentation. Sections nest with :func:`section`;
``tuple[X, ...]`` of a section dataclass is a list of such sections in YAML.
The loader (:mod:`rakectl.config.loader`) validates against these declarations and
``rakectl config-docs`` renders them (pure: no file or YAML handling here).
"""

from __future__ import annotations

import math
import operator
from dataclasses import MISSING, dataclass, field
from typing import Any


@dataclass(frozen=True)
class Bounds:
    """Numeric bounds of an option; None means unbounded on that side."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None

    def violation(self, value: float) -> str | None:
        """Why ``value`` is out of bounds, or None if it is inside."""
        if not math.isfinite(value):
            return f"must be finite, got {value}"
        for limit, op, ok in (
            (self.gt, ">", operator.gt),
            (self.ge, ">=", operator.ge),
            (self.lt, "<", operator.lt),
            (self.le, "<=", operator.le),
        ):
            if limit is not None and not ok(value, limit):
                return f"must be {op} {limit:g}, got {value:g}"
        return None

    def describe(self) -> str:
        parts = []
        for limit, op in ((self.gt, ">"), (self.ge, "≥"), (self.lt, "<"), (self.le, "≤")):
            if limit is not None:
                parts.append(f"{op} {limit:g}")
        return ", ".join(parts)


def setting(
    default: Any,
    doc: str,
    *,
    unit: str = "",
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    whole_items: bool = False,
) -> Any:
    """Declare an option: default, documentation, unit and bounds in one place.
    ``whole_items``: a list of sections each of whose items must give every option (no
    item's option defaults: a survey point missing its height is refused, not put at 0)."""
    meta = {"doc": doc, "unit": unit, "bounds": Bounds(gt=gt, ge=ge, lt=lt, le=le),
            "whole_items": whole_items}
    if isinstance(default, tuple):
        return field(default_factory=lambda: default, metadata=meta)
    return field(default=default, metadata=meta)


def section(cls: type, default: Any = None, doc: str | None = None) -> Any:
    """Declare a nested section; its default is ``default`` or the section's own defaults."""
    factory = cls if default is None else (lambda: default)
    return field(default_factory=factory, metadata={"doc": doc or (cls.__doc__ or "").strip()})


def has_default(f: Any) -> bool:
    return bool(f.default is not MISSING or f.default_factory is not MISSING)
