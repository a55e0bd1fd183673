"""The viewer's topics: one publisher that logs the rake's state to every sink of a
Foxglove context (a live WebSocket server, an MCAP file, or both).

Topics (docs/viewer.md has the schemas and the shipped layout):

- ``/rake`` (foxglove.SceneUpdate): the rake in its vertical plane, a line from the
  pivot to the tip and a ball at the tip; frame ``plane``: x along the reach, z up,
  y = 0, ground level z = 0.
- ``/ground`` (foxglove.SceneUpdate): ground level over the lane, the depth reached so
  far, the buried objects known (the emulated bench's), the object found.
- ``/force`` (JSON): F̂, the current-based force, the clamp's worst-case push, its
  budget and its limit, and, on the emulated bench, the true vertical force.
- ``/voltage`` (JSON): the voltages the controller asked for and those the clamp let
  through.
- ``/state`` (JSON): the state machine's state, the supervision's level, the fault, the
  excavation's phase and cycle.
- ``/timing`` (JSON): the loop's wake-up latency and late ticks (live only).
- ``/truth`` (JSON): the emulator's ground truth (emulated bench and recordings only).
"""

from __future__ import annotations

import json
import math
import types
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from rakectl.errors import RakeError

try:
    import foxglove
    from foxglove.channels import SceneUpdateChannel
    from foxglove.messages import (
        Color,
        CubePrimitive,
        LinePrimitive,
        LinePrimitiveLineType,
        Point3,
        Pose,
        SceneEntity,
        SceneUpdate,
        SpherePrimitive,
        Vector3,
    )
except ImportError as exc:  # the [view] extra is optional on the robot
    raise RakeError(f"the viewer needs the [view] extra: pip install 'rakectl[view]' ({exc})"
                    ) from exc



def require_foxglove() -> types.ModuleType:
    """The foxglove SDK (imported above, or this module would not have loaded)."""
    return foxglove


FRAME = "plane"
GROUND_REACH_M = (0.3, 1.7)  # the lane's extent drawn when none is known


def _number(*names: str) -> dict[str, Any]:
    return {name: {"type": ["number", "null"]} for name in names}


JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    "/force": {"type": "object", "properties": _number(
        "f_hat_n", "f_current_n", "clamp_worst_case_n", "clamp_budget_n",
        "clamp_limit_n")},
    "/voltage": {"type": "object", "properties": _number(
        "requested_r_v", "requested_theta_v", "applied_r_v", "applied_theta_v")},
    "/state": {"type": "object", "properties": {
        "state": {"type": "string"}, "level": {"type": ["string", "null"]},
        "fault": {"type": ["string", "null"]}, "phase": {"type": ["string", "null"]},
        "cycle": {"type": ["integer", "null"]}, "lane": {"type": ["integer", "null"]}}},
    "/timing": {"type": "object", "properties": _number(
        "latency_p50_us", "latency_p99_us", "latency_max_us", "late_ticks", "ticks")},
    "/truth": {"type": "object", "properties": {
        **_number("force_down_n", "force_drag_n", "mine_plate_max_n", "mine_side_max_n",
                  "tip_reach_m", "tip_height_m"),
        "contact": {"type": "string"}, "mine_activated": {"type": "boolean"}}},
}
SCENE_TOPICS = ("/rake", "/ground")


def schema_name(topic: str) -> str:
    """A JSON topic's schema name: ``/force`` → ``rakectl.Force``."""
    return "rakectl." + topic.strip("/").capitalize()

TOPICS = SCENE_TOPICS + tuple(JSON_SCHEMAS)


@dataclass(frozen=True)
class Box:
    """A buried object as drawn: centre reach, top depth, width, thickness, kind."""

    reach_m: float
    depth_m: float
    width_m: float
    thickness_m: float
    kind: str = "mine"


_COLOURS = {"mine": Color(r=0.85, g=0.1, b=0.1, a=0.8), "stone": Color(r=0.5, g=0.5, b=0.5, a=0.8),
            "root": Color(r=0.55, g=0.35, b=0.15, a=0.8)}
_GROUND = Color(r=0.45, g=0.3, b=0.1, a=1.0)
_REACHED = Color(r=0.9, g=0.6, b=0.1, a=1.0)
_RAKE = Color(r=0.1, g=0.4, b=0.9, a=1.0)


def _clean(values: Mapping[str, Any]) -> dict[str, Any]:
    """JSON-safe: a non-finite number is written as null."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in values.items()}


def _point(reach_m: float, height_m: float) -> Point3:
    return Point3(x=reach_m, y=0.0, z=height_m)


class Publisher:
    """The topics' channels in one context; each method logs one message at ``time_ns``
    (nanoseconds since the Unix epoch) to every sink of the context."""

    def __init__(self, context: foxglove.Context) -> None:
        self._scenes = {topic: SceneUpdateChannel(topic, context=context)
                        for topic in SCENE_TOPICS}
        self._json = {topic: foxglove.Channel(
            topic, message_encoding="json", context=context,
            schema=foxglove.Schema(name=schema_name(topic), encoding="jsonschema",
                                   data=json.dumps(schema).encode()))
            for topic, schema in JSON_SCHEMAS.items()}

    def json(self, topic: str, time_ns: int, values: Mapping[str, Any]) -> None:
        self._json[topic].log(_clean(values), log_time=time_ns)

    def rake(self, time_ns: int, pivot_height_m: float, reach_m: float, height_m: float
             ) -> None:
        """The rake from the pivot (reach 0) to the tip."""
        if not all(math.isfinite(v) for v in (pivot_height_m, reach_m, height_m)):
            return
        line = LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.03,
                             points=[_point(0.0, pivot_height_m), _point(reach_m, height_m)],
                             color=_RAKE)
        tip = SpherePrimitive(pose=Pose(position=Vector3(x=reach_m, y=0.0, z=height_m)),
                              size=Vector3(x=0.03, y=0.03, z=0.03), color=_RAKE)
        entity = SceneEntity(frame_id=FRAME, id="rake", lines=[line], spheres=[tip])
        self._scenes["/rake"].log(SceneUpdate(entities=[entity]), log_time=time_ns)

    def ground(self, time_ns: int, lane_m: tuple[float, float] | None,
               depth_reached_m: float | None, objects: Iterable[Box],
               found: tuple[float, float] | None) -> None:
        """Ground level, the depth reached over the lane, the objects, the one found."""
        near_m, far_m = lane_m if lane_m is not None else GROUND_REACH_M
        lines = [LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.01,
                               points=[_point(GROUND_REACH_M[0], 0.0),
                                       _point(GROUND_REACH_M[1], 0.0)], color=_GROUND)]
        if depth_reached_m is not None and math.isfinite(depth_reached_m):
            lines.append(LinePrimitive(
                type=LinePrimitiveLineType.LineStrip, thickness=0.01,
                points=[_point(near_m, -depth_reached_m), _point(far_m, -depth_reached_m)],
                color=_REACHED))
        cubes = [CubePrimitive(
            pose=Pose(position=Vector3(x=b.reach_m, y=0.0, z=-b.depth_m - 0.5 * b.thickness_m)),
            size=Vector3(x=b.width_m, y=0.1, z=b.thickness_m),
            color=_COLOURS.get(b.kind, _COLOURS["stone"])) for b in objects]
        spheres = []
        if found is not None:
            spheres.append(SpherePrimitive(
                pose=Pose(position=Vector3(x=found[0], y=0.0, z=-found[1])),
                size=Vector3(x=0.04, y=0.04, z=0.04), color=Color(r=1.0, g=0.0, b=1.0, a=1.0)))
        entity = SceneEntity(frame_id=FRAME, id="ground", lines=lines, cubes=cubes,
                             spheres=spheres)
        self._scenes["/ground"].log(SceneUpdate(entities=[entity]), log_time=time_ns)
