"""The command API's replies on the wire (pure): one JSON object a line,
``{"ok": true, …}`` or ``{"ok": false, "error": "<one sentence>"}``, with the request's
``"id"`` when it had one (:mod:`rakectl.api.schema` has the requests)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


def _encode(message: Mapping[str, Any]) -> bytes:
    try:
        text = json.dumps(message, allow_nan=False, separators=(",", ":"))
    except ValueError:  # NaN or infinity: strict JSON has none, they go out as null
        text = json.dumps(_finite(message), separators=(",", ":"))
    return text.encode() + b"\n"


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def sentence(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def error_reply(error: str, request_id: str | int | None = None) -> bytes:
    reply: dict[str, Any] = {"ok": False}
    if request_id is not None:
        reply["id"] = request_id
    reply["error"] = error
    return _encode(reply)


def ok_reply(payload: Mapping[str, Any], request_id: str | int | None = None) -> bytes:
    if not isinstance(payload, Mapping):
        raise TypeError(f"the handler returned {type(payload).__name__}, not a mapping")
    for key in ("ok", "id", "error"):
        if key in payload:
            raise ValueError(f"the handler's reply uses the reserved key {key!r}")
    head: dict[str, Any] = {"ok": True} if request_id is None else {"ok": True, "id": request_id}
    return _encode(head | dict(payload))
