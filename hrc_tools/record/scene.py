"""``foxglove.SceneUpdate`` messages of the cell's capsules, for the 3D panel of Foxglove and Lichtblick.

A capsule (segment ``a``–``b`` swept by a sphere of ``radius``) is drawn as a ``CylinderPrimitive`` between its
ends and a ``SpherePrimitive`` at each end; a point capsule (``a == b``) is one sphere. People come from the
trackers' frames (one entity per person, per tracker), robots from the gateway's status (one entity per robot,
its links coloured by zone; an open robot's plan around people as a ``LinePrimitive`` through the tool's positions
along it, ``robots.<name>.plan.path_tool_m``). Entities carry a short lifetime so that whoever leaves the cell, or a
plan that ends, vanishes.

The channel's schema is Foxglove's own (:func:`foxglove_schema`, vendored from ``@foxglove/schemas``), so
whatever passes it, Foxglove reads; the 3D panel recognises the channel by the schema name
``foxglove.SceneUpdate``. The models below build the messages (JSON encoding: times as ``{sec, nsec}``); they fill
a part of that schema and every message they make is valid against it (``tests/test_recording.py``). Pure: no
I/O but reading the vendored schema, every time is passed in.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from importlib import resources
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from hrc_contract.messages import Humans
from hrc_contract.status_models import CapsuleStatus, GatewayStatus
from hrc_contract.vocabulary import ZoneName

SCHEMA_NAME = "foxglove.SceneUpdate"
FOXGLOVE_SCHEMAS_VERSION = "2.1.0"
"""The version of the npm package ``@foxglove/schemas`` (MIT) that :data:`FOXGLOVE_SCHEMA_FILE` comes from."""
FOXGLOVE_SCHEMA_FILE = "schemas/foxglove.SceneUpdate.json"
"""Foxglove's JSON Schema of ``foxglove.SceneUpdate``, in this package (``hrc_tools/record/schemas/README.md``)."""
FOXGLOVE_SCHEMA_SHA256 = "bc563208a8b4bb2eaecd17713405ef2d9ba87264ac73ae375ba5ab30368c8991"
"""SHA-256 of :data:`FOXGLOVE_SCHEMA_FILE` as vendored (the tests check it: the file is not edited by hand)."""
WORLD_FRAME = "world"
"""The cell's world frame (``frame_id`` of every entity)."""
HUMAN_LIFETIME_S = 0.3
"""A person not seen again within this is removed from the scene (about 9 frames at 30 Hz) [s]."""
ROBOT_LIFETIME_S = 0.5
"""A robot without a new status within this is removed (the status comes at 25 Hz) [s]."""
NS_PER_S = 1_000_000_000
PARALLEL_EPS = 1e-12


def foxglove_schema_bytes() -> bytes:
    """The vendored file :data:`FOXGLOVE_SCHEMA_FILE`, as it is."""
    return resources.files("hrc_tools.record").joinpath(FOXGLOVE_SCHEMA_FILE).read_bytes()


def foxglove_schema() -> dict[str, Any]:
    """Foxglove's JSON Schema of ``foxglove.SceneUpdate`` (``@foxglove/schemas`` :data:`FOXGLOVE_SCHEMAS_VERSION`)."""
    schema: dict[str, Any] = json.loads(foxglove_schema_bytes())
    return schema


class _Fox(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Time(_Fox):
    sec: int = Field(ge=0)
    nsec: int = Field(ge=0, le=999_999_999)


class Duration(_Fox):
    sec: int = 0
    nsec: int = Field(0, ge=0, le=999_999_999)


class Vector3(_Fox):
    x: float
    y: float
    z: float


class Quaternion(_Fox):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Pose(_Fox):
    position: Vector3
    orientation: Quaternion


class Color(_Fox):
    r: float = Field(ge=0.0, le=1.0)
    g: float = Field(ge=0.0, le=1.0)
    b: float = Field(ge=0.0, le=1.0)
    a: float = Field(ge=0.0, le=1.0)


class SpherePrimitive(_Fox):
    pose: Pose
    size: Vector3 = Field(description="Diameter along each axis [m].")
    color: Color


class CylinderPrimitive(_Fox):
    pose: Pose = Field(description="Centre of the cylinder; its axis is the pose's +z.")
    size: Vector3 = Field(description="Diameter in x and y, height in z [m].")
    bottom_scale: float = 1.0
    top_scale: float = 1.0
    color: Color


class Point3(_Fox):
    x: float
    y: float
    z: float


class LinePrimitive(_Fox):
    """Points joined by lines; ``type`` 0 is ``LINE_STRIP`` (0-1, 1-2, …)."""

    type: int = Field(0, ge=0, le=2, description="0: LINE_STRIP, 1: LINE_LOOP, 2: LINE_LIST.")
    pose: Pose = Field(description="The points' frame relative to the entity's frame.")
    thickness: float = Field(ge=0.0, description="[m], or [px] with ``scale_invariant``.")
    scale_invariant: bool = False
    points: list[Point3]
    color: Color
    colors: list[Color] = Field(default_factory=list)
    indices: list[int] = Field(default_factory=list)


class KeyValuePair(_Fox):
    key: str
    value: str


class SceneEntity(_Fox):
    timestamp: Time
    frame_id: str
    id: str
    lifetime: Duration
    frame_locked: bool = False
    metadata: list[KeyValuePair] = Field(default_factory=list)
    arrows: list[dict[str, Any]] = Field(default_factory=list)
    cubes: list[dict[str, Any]] = Field(default_factory=list)
    spheres: list[SpherePrimitive] = Field(default_factory=list)
    cylinders: list[CylinderPrimitive] = Field(default_factory=list)
    lines: list[LinePrimitive] = Field(default_factory=list)
    triangles: list[dict[str, Any]] = Field(default_factory=list)
    texts: list[dict[str, Any]] = Field(default_factory=list)
    models: list[dict[str, Any]] = Field(default_factory=list)


class SceneEntityDeletion(_Fox):
    timestamp: Time
    type: int = Field(ge=0, le=1, description="0: the entity ``id``; 1: every entity of the topic.")
    id: str


class SceneUpdate(_Fox):
    """An update to the entities displayed in a 3D scene (``foxglove.SceneUpdate``)."""

    deletions: list[SceneEntityDeletion] = Field(default_factory=list)
    entities: list[SceneEntity] = Field(default_factory=list)


HUMAN_COLOR = Color(r=0.2, g=0.45, b=1.0, a=0.6)
PLAN_COLOR = Color(r=0.31, g=0.89, b=0.84, a=0.9)
"""A plan's path (the operator page's colour for it)."""
PLAN_THICKNESS_M = 0.015
ZONE_COLORS: dict[ZoneName, Color] = {
    "autonomous": Color(r=0.2, g=0.75, b=0.3, a=0.8),
    "guarded_distance": Color(r=0.95, g=0.85, b=0.2, a=0.8),
    "reduced_speed": Color(r=1.0, g=0.55, b=0.1, a=0.8),
    "safety_exception": Color(r=0.9, g=0.15, b=0.15, a=0.8),
}


def stamp(t_ns: int) -> Time:
    """A Foxglove time from ns since the Unix epoch."""
    sec, nsec = divmod(max(0, t_ns), NS_PER_S)
    return Time(sec=sec, nsec=nsec)


def duration(t_s: float) -> Duration:
    sec, nsec = divmod(round(t_s * NS_PER_S), NS_PER_S)
    return Duration(sec=sec, nsec=nsec)


def z_to(direction: Sequence[float]) -> Quaternion:
    """The shortest rotation taking +z onto the unit vector ``direction`` (the cylinder's axis).

    For unit vectors u, v: q = (w = 1 + u·v, xyz = u × v), normalised; with u = +z, u × v = (−v_y, v_x, 0).
    Opposite vectors (v = −z) have no unique shortest rotation: half a turn about +x.
    """
    x, y, z = direction
    w = 1.0 + z
    if w < PARALLEL_EPS:
        return Quaternion(x=1.0, y=0.0, z=0.0, w=0.0)
    norm = math.sqrt(w * w + x * x + y * y)
    return Quaternion(x=-y / norm, y=x / norm, z=0.0, w=w / norm)


def _sphere(p: Sequence[float], radius_m: float, color: Color) -> SpherePrimitive:
    d = 2.0 * radius_m
    return SpherePrimitive(
        pose=Pose(position=Vector3(x=p[0], y=p[1], z=p[2]), orientation=Quaternion()),
        size=Vector3(x=d, y=d, z=d),
        color=color,
    )


def capsule_primitives(
    a_m: Sequence[float], b_m: Sequence[float], radius_m: float, color: Color
) -> tuple[list[CylinderPrimitive], list[SpherePrimitive]]:
    """A capsule as a cylinder from ``a_m`` to ``b_m`` and a sphere at each end (one sphere for a point) [m]."""
    axis = [b - a for a, b in zip(a_m, b_m, strict=True)]
    length_m = math.sqrt(sum(c * c for c in axis))
    if length_m < PARALLEL_EPS:
        return [], [_sphere(a_m, radius_m, color)]
    centre = [(a + b) / 2.0 for a, b in zip(a_m, b_m, strict=True)]
    d = 2.0 * radius_m
    cylinder = CylinderPrimitive(
        pose=Pose(
            position=Vector3(x=centre[0], y=centre[1], z=centre[2]),
            orientation=z_to([c / length_m for c in axis]),
        ),
        size=Vector3(x=d, y=d, z=length_m),
        color=color,
    )
    return [cylinder], [_sphere(a_m, radius_m, color), _sphere(b_m, radius_m, color)]


def _entity(
    entity_id: str,
    t_ns: int,
    lifetime_s: float,
    capsules: Iterable[tuple[Sequence[float], Sequence[float], float]],
    color: Color,
    metadata: dict[str, str],
) -> SceneEntity:
    cylinders: list[CylinderPrimitive] = []
    spheres: list[SpherePrimitive] = []
    for a_m, b_m, radius_m in capsules:
        c, s = capsule_primitives(a_m, b_m, radius_m, color)
        cylinders += c
        spheres += s
    return SceneEntity(
        timestamp=stamp(t_ns),
        frame_id=WORLD_FRAME,
        id=entity_id,
        lifetime=duration(lifetime_s),
        metadata=[KeyValuePair(key=k, value=v) for k, v in metadata.items()],
        spheres=spheres,
        cylinders=cylinders,
    )


def humans_scene(frame: Humans, t_ns: int) -> SceneUpdate:
    """One entity per person of a tracker frame, id ``<tracker>/<person>``, shown at ``t_ns`` (its arrival)."""
    return SceneUpdate(
        entities=[
            _entity(
                f"{frame.tracker}/{human.id}",
                t_ns,
                HUMAN_LIFETIME_S,
                ((c.a, c.b, c.radius) for c in human.capsules),
                HUMAN_COLOR,
                {"tracker": frame.tracker, "capsules": str(len(human.capsules))},
            )
            for human in frame.humans
        ]
    )


def _link_capsules(links: Iterable[CapsuleStatus]) -> Iterable[tuple[Sequence[float], Sequence[float], float]]:
    return ((link.a_m, link.b_m, link.radius_m) for link in links)


def plan_entity(name: str, path_m: Sequence[Sequence[float]], reason: str, t_ns: int) -> SceneEntity:
    """The plan robot ``name`` follows as a line through the tool's positions along it, id ``plan/<name>`` [m]."""
    return SceneEntity(
        timestamp=stamp(t_ns),
        frame_id=WORLD_FRAME,
        id=f"plan/{name}",
        lifetime=duration(ROBOT_LIFETIME_S),
        metadata=[KeyValuePair(key="reason", value=reason), KeyValuePair(key="points", value=str(len(path_m)))],
        lines=[
            LinePrimitive(
                pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion()),
                thickness=PLAN_THICKNESS_M,
                points=[Point3(x=p[0], y=p[1], z=p[2]) for p in path_m],
                color=PLAN_COLOR,
            )
        ],
    )


def robots_scene(status: GatewayStatus, t_ns: int) -> SceneUpdate:
    """One entity per robot of a status document, id ``robot/<name>``, its links coloured by its zone; and for an
    open robot following a plan around people, the plan's tool path as a line, id ``plan/<name>`` (it vanishes
    with the plan: no status carries it again, its lifetime ends)."""
    plans = [
        plan_entity(name, robot.plan.path_tool_m, robot.plan.reason, t_ns)
        for name, robot in status.robots.items()
        if robot.plan is not None and robot.plan.path_tool_m
    ]
    return SceneUpdate(
        entities=plans
        + [
            _entity(
                f"robot/{name}",
                t_ns,
                ROBOT_LIFETIME_S,
                _link_capsules(robot.links),
                ZONE_COLORS[robot.zone],
                {
                    "zone": robot.zone,
                    "delta": f"{robot.delta:.3f}",
                    "min_distance_m": "-" if robot.min_distance_m is None else f"{robot.min_distance_m:.3f}",
                },
            )
            for name, robot in status.robots.items()
        ]
    )
