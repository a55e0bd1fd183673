"""The command API's replies on the wire (pure): one JSON object a line,
``{"ok": true, …}`` or ``{"ok": false, "error": "<one sentence>"}``, with the request's
``"id"`` when it had one (:mod:`rakectl.api.schema` has the requests); and what the
operator's commands say from them (a pose, a lane's progress and end, the next step
after a refusal)."""

from __future__ import annotations

import json
import math
import re
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


# --------------------------------------------------------------------------- read back

# after a refusal in these states, the commands to run next (jog, excavate, arm)
NEXT_STEPS = {"estop": ("reset", "arm"), "fault": ("reset", "arm"), "disarmed": ("arm",)}


def pose_text(reply: Mapping[str, Any]) -> str:
    """Where the tip is, as the status says it."""
    tip = reply.get("tip") or {}
    reach_m, depth_m = tip.get("reach_m"), tip.get("depth_m")
    if reach_m is None or depth_m is None:
        return "no pose (no joint feedback)"
    return f"reach {reach_m:.3f} m, depth {1e3 * depth_m:.1f} mm"


def lane_text(reply: Mapping[str, Any]) -> str:
    """The lane's cycle, depth and largest force estimate, as the status says them."""
    ex = reply.get("excavation") or {}
    if not ex:
        return "no lane"
    return (f"cycle {ex['cycle']}, depth {1e3 * ex['depth_m']:.0f}/"
            f"{1e3 * ex['target_depth_m']:.0f} mm, "
            f"F̂ max {(reply.get('force') or {}).get('f_hat_max_n', math.nan):.1f} N")


def lane_identity_text(reply: Mapping[str, Any]) -> str:
    """Which lane the status's excavation is: its number since the daemon started, and
    its parameters ("" from a daemon that does not say them)."""
    lane = (reply.get("excavation") or {}).get("lane")
    if not lane:
        return ""
    text = (f"lane {lane['number']}: reach {lane['reach_far_m']:.3f} → "
            f"{lane['reach_near_m']:.3f} m, target {1e3 * lane['target_depth_m']:g} mm, ")
    cuts = (f"step {1e3 * lane['depth_step_m']:g} mm, stroke "
            f"{lane['stroke_speed_m_per_s']:g} m/s")
    if lane.get("adaptive"):
        return text + f"force-adaptive (first {cuts})"
    return text + cuts


def jog_caps_text(reply: Mapping[str, Any]) -> str:
    """The fastest the daemon jogs, as the status says it ("" from a daemon that does not
    say it)."""
    caps = reply.get("jog")
    if not caps:
        return ""
    return (f"reach and height {caps['max_tip_speed_m_per_s']:g} m/s each, r "
            f"{caps['max_r_speed_m_per_s']:g} m/s, θ {caps['max_theta_speed_rad_per_s']:g} "
            "rad/s (faster requests move at these)")


def progress_text(reply: Mapping[str, Any]) -> str:
    """The progress bar's text: the lane's phase too, and a find or a force-limit stop."""
    ex = reply["excavation"]
    found = ex.get("object_found")
    text = (f"excavate   cycle {ex['cycle']}, depth {1e3 * ex['depth_m']:.0f}/"
            f"{1e3 * ex['target_depth_m']:.0f} mm, {ex['phase']}, "
            f"F̂ max {reply['force']['f_hat_max_n']:.1f} N")
    if found:
        text += (f", OBJECT FOUND at reach {found['reach_m']:.3f} m, depth "
                 f"{1e3 * found['depth_m']:.0f} mm")
    elif ex.get("stopped_by_force"):
        text += ", STOPPED BY THE FORCE LIMIT (lane not finished)"
    return text


def excavation_outcome(reply: Mapping[str, Any]) -> tuple[bool, str]:
    """How a lane ended, from the daemon's status once it no longer excavates: whether it
    completed (the target depth reached, held by the descent limit, or an object found)
    and one line saying how, with what to do next when it did not."""
    ex, state, lane = reply.get("excavation") or {}, reply.get("state"), lane_text(reply)
    unfinished = f"({lane}): the lane is not finished"
    if state == "hold" and ex.get("done"):
        found = ex.get("object_found")
        if found:
            return True, (f"excavate: OBJECT FOUND at reach {found['reach_m']:.3f} m, depth "
                          f"{1e3 * found['depth_m']:.0f} mm ({lane})")
        if ex.get("stopped_by_force"):
            return False, f"excavate: STOPPED BY THE FORCE LIMIT {unfinished}"
        if ex.get("held_by_descent"):
            return True, (f"excavate: done as deep as the descent limit allows ({lane}; the "
                          "declared soil's step holds it short of the target: descent.*)")
        return True, f"excavate: done, target depth reached ({lane})"
    if state == "hold":  # the lane's hold without done: a stop
        return False, f"excavate: STOPPED by an operator's `rakectl stop` {unfinished}"
    if state in ("fault", "estop"):
        what = "FAULT" if state == "fault" else "EMERGENCY STOP"
        reason = f": {reply['fault']}" if reply.get("fault") else ""
        return False, (f"excavate: {what}{reason} {unfinished}; `rakectl reset`, then "
                       "`rakectl arm`")
    if state == "disarmed":
        return False, f"excavate: DISARMED (`rakectl disarm`) {unfinished}"
    return False, f"excavate: the daemon is {state} {unfinished}"


def next_step(error: str, state: str | None) -> str:
    """The commands to run next after ``error``, a refusal of a command that needs the rake
    armed, in the daemon's ``state``: "" when there are none, or when the sentence already
    names them (the refused command itself aside)."""
    steps = NEXT_STEPS.get(state or "", ())
    said = re.sub(r"^cannot \w+", "", error)
    if not steps or all(re.search(rf"\b{step}\b", said) for step in steps):
        return ""
    return ", then ".join(f"`rakectl {step}`" for step in steps)
