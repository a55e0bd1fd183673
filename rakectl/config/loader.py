"""Load configuration files into frozen :mod:`rakectl.config.settings` objects.

Every error is one line naming where it is, ``FILE:LINE: dotted.key message``
(``--set dotted.key=value: …`` for command-line overrides), raised as
:class:`~rakectl.errors.ConfigError`. Unknown keys are rejected; values are
checked against the bounds declared in :mod:`rakectl.config.settings`.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import re
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Protocol, TypeVar

import yaml

from rakectl.config.settings import Bounds, Settings, has_default
from rakectl.errors import ConfigError

T = TypeVar("T")

# YAML 1.1 (PyYAML) reads 1.33e4 as a string; accept YAML 1.2 number literals.
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


@dataclasses.dataclass(frozen=True)
class _Value:
    """A raw value with where it came from (for error messages)."""

    value: Any
    where: str
    text: str | None = None  # a scalar's text as written (YAML 1.1 reads "on" as True)


def _where(source: str, node: yaml.Node) -> str:
    return f"{source}:{node.start_mark.line + 1}"


def _scalar(source: str, node: yaml.Node) -> Any:
    """A scalar node's value as PyYAML's safe loader resolves it; ConfigError naming the
    line for what it cannot construct (an explicit tag, a merge key)."""
    try:
        return yaml.constructor.SafeConstructor().construct_object(node)
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{_where(source, node)}: unsupported YAML: {problem}") from None


def _plain(source: str, node: yaml.Node, within: frozenset[int] = frozenset()) -> Any:
    """A YAML node as nested dicts/lists whose leaves are _Value (``within``: the
    collections it is inside, by id: an alias to one of them is refused)."""
    if isinstance(node, yaml.MappingNode | yaml.SequenceNode):
        if id(node) in within:
            raise ConfigError(f"{_where(source, node)}: a value that contains itself (an "
                              "alias to a collection around it)")
        within |= {id(node)}
    if isinstance(node, yaml.MappingNode):
        out: dict[str, Any] = {}
        for key_node, value_node in node.value:
            key = _scalar(source, key_node) if isinstance(key_node, yaml.ScalarNode) else None
            if not isinstance(key, str):
                raise ConfigError(f"{_where(source, key_node)}: keys must be strings, got "
                                  f"{key!r}")
            if key in out:
                raise ConfigError(f"{_where(source, key_node)}: {key} is given twice")
            out[key] = (_where(source, key_node), _plain(source, value_node, within))
        return out
    if isinstance(node, yaml.SequenceNode):
        return [(_where(source, item), _plain(source, item, within)) for item in node.value]
    return _Value(_scalar(source, node), _where(source, node), node.value)


class _ExplicitTag(yaml.YAMLError):
    def __init__(self, tag: str, mark: yaml.Mark) -> None:
        super().__init__(tag)
        self.problem = f"the explicit tag {tag!r}: write the value as it is, untagged"
        self.problem_mark = mark


class _UntaggedLoader(yaml.SafeLoader):
    """The safe loader refusing a tag written out (``!!str 3``, ``!!bool "yes"``, ``!foo``):
    a value is read as it is written, never as a tag would make it."""

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        event = self.peek_event()  # type: ignore[no-untyped-call]
        tag = None if isinstance(event, yaml.AliasEvent) else getattr(event, "tag", None)
        if tag is not None:
            raise _ExplicitTag(tag, event.start_mark)
        return super().compose_node(parent, index)


def parse_yaml(text: str, source: str) -> dict[str, Any]:
    """Parse YAML text into the annotated tree the validator reads."""
    try:
        node = yaml.compose(text, Loader=_UntaggedLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        kind = "unsupported" if isinstance(exc, _ExplicitTag) else "malformed"
        raise ConfigError(f"{source}{line}: {kind} YAML: {problem}") from None
    if node is None:
        return {}
    if not isinstance(node, yaml.MappingNode):
        raise ConfigError(f"{_where(source, node)}: the top level must be a mapping of sections")
    tree = _plain(source, node)
    assert isinstance(tree, dict)
    return tree


def _annotate(value: Any, where: str) -> Any:
    """A plain value (from --set) in the annotated form that _plain gives for files."""
    if isinstance(value, dict):
        return {str(k): (where, _annotate(v, where)) for k, v in value.items()}
    if isinstance(value, list):
        return [(where, _annotate(item, where)) for item in value]
    return _Value(value, where)


def _apply_override(tree: dict[str, Any], assignment: str) -> None:
    where = f"--set {assignment}"
    key, sep, text = assignment.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"{where}: expected dotted.key=value")
    try:
        composed = yaml.compose(text, Loader=_UntaggedLoader)  # parsed once, then
        value = "" if not text.strip() else None  # refused as a file refuses it (merge
        if composed is not None:  # keys, an alias to a collection around it), else
            _plain(where, composed)  # constructed as safe_load does; nothing: ""
            value = yaml.constructor.SafeConstructor().construct_document(composed)
    except _ExplicitTag as exc:
        raise ConfigError(f"{where}: unsupported YAML: {exc.problem}") from None
    except yaml.YAMLError:
        value = text
    parts = key.strip().split(".")
    node = tree
    for part in parts[:-1]:
        entry = node.get(part)
        if entry is None or not isinstance(entry[1], dict):
            entry = (where, {})
            node[part] = entry
        node = entry[1]
    leaf = _Value(value, where, text.strip()) if not isinstance(value, dict | list) \
        else _annotate(value, where)
    node[parts[-1]] = (where, leaf)


def _suggest(key: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(key, list(known), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


def _coerce(tp: Any, raw: _Value, dotted: str, bounds: Bounds | None) -> Any:
    value, where = raw.value, raw.where
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        choices = ", ".join(m.value for m in tp)
        if isinstance(value, bool):  # YAML 1.1 reads off/on/yes/no as booleans: as written
            value = raw.text.lower() if raw.text is not None else str(value).lower()
        if value not in {m.value for m in tp}:
            raise ConfigError(f"{where}: {dotted} must be one of {choices}, got {value!r}")
        return tp(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {dotted} must be true or false, got {value!r}")
        return value
    if tp in (int, float):
        if raw.text is not None and isinstance(value, int | float) and not isinstance(
                value, bool):  # as written: YAML 1.1 reads 010 as 8, 0b11 as 3, 1:40 as 100
            value = _as_written(raw.text.strip(), value, where, dotted)
        if isinstance(value, str) and _HEX_OCTAL.fullmatch(value.strip()):  # YAML 1.1: text
            value = int(value.strip(), 0)
        if isinstance(value, str) and _NUMBER.fullmatch(value.strip()):
            if tp is int and not value.strip().lstrip("+-").isdigit():
                raise ConfigError(f"{where}: {dotted} must be a whole number, got {value!r}")
            value = float(value) if tp is float else int(value)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: {dotted} must be a number, got {value!r}")
        if tp is int and not isinstance(value, int):
            raise ConfigError(f"{where}: {dotted} must be a whole number, got {value!r}")
        try:
            as_float = float(value)
        except OverflowError:  # a whole number past any float: no bound can judge it
            raise ConfigError(f"{where}: {dotted} must be finite, got a whole number of "
                              f"{len(str(abs(value)))} digits") from None
        problem = bounds.violation(as_float) if bounds else None
        if problem:
            raise ConfigError(f"{where}: {dotted} {problem}")
        return tp(value)
    if tp is str:
        if value is None:
            raise ConfigError(f'{where}: {dotted} must be a string, got no value (an empty '
                              f'one: "")')
        if not isinstance(value, str):
            raise ConfigError(f"{where}: {dotted} must be a string, got {value!r}")
        if "\0" in value:  # no path, group or channel name holds one
            raise ConfigError(f"{where}: {dotted} must not contain a NUL character")
        return value
    raise ConfigError(f"{where}: {dotted} has unsupported type {tp!r}")  # pragma: no cover


def _as_written(text: str, value: float, where: str, dotted: str) -> float:
    """A number as its text reads in YAML 1.2: decimal, 0x hexadecimal, 0o octal
    (infinities and NaN as resolved, for the bounds to judge); ConfigError for what
    only YAML 1.1 reads as a number, and for a leading zero, which each reads its way."""
    if _INFINITE.fullmatch(text):
        return value
    if _HEX_OCTAL.fullmatch(text):
        return int(text, 0)
    if not _NUMBER.fullmatch(text):
        raise ConfigError(f"{where}: {dotted} must be a number in decimal, 0x hexadecimal "
                          f"or 0o octal (YAML 1.2), got {text!r}")
    if re.fullmatch(r"[-+]?0\d+", text):
        raise ConfigError(f"{where}: {dotted}: {text!r} has a leading zero (YAML 1.1 reads "
                          f"it as octal, YAML 1.2 as decimal): write it without")
    return int(text) if re.fullmatch(r"[-+]?\d+", text) else float(text)


_INFINITE = re.compile(r"[-+]?\.(inf|Inf|INF)|\.(nan|NaN|NAN)")
_HEX_OCTAL = re.compile(r"[-+]?0(x[0-9a-fA-F]+|o[0-7]+)")


def _build(cls: type[T], tree: Mapping[str, Any], prefix: str, where: str,
           base: T | None = None, whole: bool = False) -> T:
    """A ``cls`` from ``tree``; an option it does not give takes ``base``'s value (the
    section's default as its parent declares it: the r motor's, not the class's), else
    the class's default; with ``whole`` every option must be given."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    for key, (key_where, _) in tree.items():
        if key not in fields:
            other = getattr(cls, "OTHER_NAMES", {}).get(key)  # its name in another root
            hint = f" (here it is {other}: {other}.…)" if other else _suggest(key, fields)
            raise ConfigError(f"{key_where}: {prefix}{key} is not a known option{hint}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if name not in tree:
            if whole or not has_default(f):
                raise ConfigError(f"{where}: {prefix}{name} is required")
            if base is not None and f.init:
                kwargs[name] = getattr(base, name)
            continue
        key_where, raw = tree[name]
        kwargs[name] = _field_value(hints[name], raw, prefix + name, key_where, f,
                                    getattr(base, name) if base is not None else _default(f))
    try:
        return cls(**kwargs)
    except ConfigError as exc:  # a section's own cross-field check
        raise ConfigError(f"{where}: {prefix.rstrip('.') or 'settings'}: {exc}") from None


def _default(f: dataclasses.Field[Any]) -> Any:
    """The field's declared default (a section's as its parent declares it), or None."""
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None if f.default is dataclasses.MISSING else f.default


def _field_value(tp: Any, raw: Any, dotted: str, where: str, f: dataclasses.Field[Any],
                 default: Any = None) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: {dotted} must be a section (a mapping of options)")
        return _build(tp, raw, dotted + ".", where, default)  # type: ignore[arg-type]
    if origin is tuple:
        item_tp = typing.get_args(tp)[0]
        if not isinstance(raw, list):
            raise ConfigError(f"{where}: {dotted} must be a list")
        return tuple(
            _list_item(item_tp, item, f"{dotted}[{i}]", item_where, f)
            for i, (item_where, item) in enumerate(raw)
        )
    if isinstance(raw, dict | list):
        raise ConfigError(f"{where}: {dotted} must be a single value, not a section or list")
    if origin in (typing.Union, types.UnionType):
        raise ConfigError(f"{where}: {dotted} has unsupported type {tp!r}")  # pragma: no cover
    return _coerce(tp, raw, dotted, f.metadata.get("bounds"))


def _list_item(tp: Any, raw: Any, dotted: str, where: str, f: dataclasses.Field[Any]) -> Any:
    if dataclasses.is_dataclass(tp):
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: {dotted} must be a section (a mapping of options)")
        return _build(tp, raw, dotted + ".", where,  # type: ignore[arg-type]
                      whole=bool(f.metadata.get("whole_items")))
    if not isinstance(raw, _Value):
        raise ConfigError(f"{where}: {dotted} must be a single value")
    return _coerce(tp, raw, dotted, f.metadata.get("bounds"))


class Checked(Protocol):
    """A configuration root: a frozen dataclass with constraints between its options."""

    def cross_checks(self) -> list[tuple[str, str]]: ...


C = TypeVar("C", bound=Checked)


def load_settings(
    path: str | Path | None = None,
    overrides: Iterable[str] = (),
    root: type[C] = Settings,  # type: ignore[assignment]
) -> C:
    """Read ``path`` (or only defaults if None), apply ``--set`` overrides, validate.

    Raises ConfigError with a one-line message naming the file, line and key.
    """
    source = str(path) if path is not None else "<defaults>"
    tree: dict[str, Any] = {}
    if path is not None:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{source}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} "
                              f"at offset {exc.start})") from None
        tree = parse_yaml(text, source)
        if not tree:
            raise ConfigError(f"{source}: no settings in the file (an empty configuration is "
                              "a mistake on a robot; leave --config out for the defaults)")
    for assignment in overrides:
        _apply_override(tree, assignment)
    settings = _build(root, tree, "", source)
    for dotted, message in settings.cross_checks():
        raise ConfigError(f"{_locate(tree, dotted, source)}: {dotted} {message}")
    return settings


def _locate(tree: Mapping[str, Any], dotted: str, source: str) -> str:
    """Where a dotted key was given, for cross-check messages."""
    node: Any = tree
    where = source
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return where
        where, node = node[part]
    return where
