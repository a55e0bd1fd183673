"""The configuration reference: Markdown tables rendered from the options' declarations."""

from __future__ import annotations

import dataclasses
import enum
import typing
from collections.abc import Collection, Iterable, Iterator
from typing import Any


def _type_name(tp: Any) -> str:
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return " \\| ".join(m.value for m in tp)
    if typing.get_origin(tp) is tuple:
        return f"list of {typing.get_args(tp)[0].__name__}"
    return getattr(tp, "__name__", str(tp))


def _show(value: Any) -> str:
    if isinstance(value, enum.Enum):
        return f"`{value.value}`"
    if isinstance(value, tuple):
        return f"{len(value)} entries" if value else "none"
    return f"`{value:g}`" if isinstance(value, float) else f"`{value}`"


def rows(cls: type, prefix: str = "", instance: Any = None,
         skip: Collection[str] = (), required: bool = False) -> Iterator[tuple[str, ...]]:
    """(key, type, default, unit, bounds, doc) for every option below ``cls``.

    Defaults are read from ``instance`` (the section's default as its parent
    declares it, e.g. the r motor's), else from a default-constructed ``cls``.
    Top-level fields named in ``skip`` are left out (a root that extends another
    documents only what it adds); ``required``: the items of a list whose every item
    gives each option (``whole_items``), with no default.
    """
    hints = typing.get_type_hints(cls)
    if instance is None:
        instance = cls()
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        tp = hints[f.name]
        value = getattr(instance, f.name)
        item = typing.get_args(tp)[0] if typing.get_origin(tp) is tuple else None
        if dataclasses.is_dataclass(tp):
            yield from rows(tp, f"{prefix}{f.name}.", value)  # type: ignore[arg-type]
            continue
        bounds = f.metadata.get("bounds")
        yield (f"{prefix}{f.name}", _type_name(tp), "required" if required else _show(value),
               f.metadata.get("unit", ""), bounds.describe() if bounds else "",
               f.metadata.get("doc", ""))
        if item is not None and dataclasses.is_dataclass(item):
            yield from rows(item, f"{prefix}{f.name}[].",  # type: ignore[arg-type]
                            required=bool(f.metadata.get("whole_items")))


def table(cls: type, prefix: str = "", skip: Collection[str] = ()) -> str:
    """A Markdown table of every option below ``cls``, keys prefixed with ``prefix``."""
    lines = ["| key | type | default | unit | bounds | meaning |", "|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows(cls, prefix, skip=skip)]
    return "\n".join(lines)


def reference(parts: Iterable[tuple[str, str]]) -> str:
    """(title, table) pairs as one Markdown document, a level-3 heading each."""
    return "\n\n".join(f"### {title}\n\n{body}" for title, body in parts)
