"""A seeded generator of sweep cases: scripted people, sensors and faulty links around one robot.

Each case is a :class:`tracker_emu.scenario.Scenario` built programmatically (valid by its validators), the
trackers that watch it (rate, noise, drops, latency; with ``occlusion``: their poses, line of sight, missed people and
id swaps) and the faults of the three links.

People enter and leave through the boundary of the volume the trackers cover (``[tracking]``, :data:`EXIT_MARGIN_M`
beyond a side face): nobody is inside it at the start, and nobody vanishes inside it. For the gateway a person who
stops being reported inside the covered volume is *lost* and stays (gateway/tracks.py), so a person who vanished
there would stop the robot for the rest of the run and the sweep would measure nothing. People are of three kinds:

- ``approach``: walks in from beyond the boundary on a bearing anywhere over the robot's front half and sides,
  straight at the robot at up to 2.0 m/s, stops 0.7–2.0 m from its base (some inside its reach), may reach in with
  one or both arms, then turns and walks out the way they came;
- ``cross``: walks across the cell in front of the robot at up to 2.0 m/s, 0.9–3 m from its base, from one side of
  the boundary to the other;
- ``standing``: walks in first (from the start of the run), stands 0.8–1.8 m from the base for the rest of the run
  and may reach in.

Link delays are drawn within the gateway's data age budget (``max_data_age_s``) for most cases, and beyond
it for some (the gateway must then see stale data and stop the robot).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from hrc_contract.config import Box, CellConfig, TrackerConfig, TrackingConfig
from hrc_tools.sim.links import LinkFault, LinkFaults
from tracker_emu.scenario import Fixture, HumanScript, Keyframe, Scenario, pose_at
from tracker_emu.sensor import covered_volume

MAX_SPEED_MPS = 2.0
"""Fastest walking speed of a generated person [m/s]."""
BEARING_LIMIT_RAD = math.radians(110.0)
"""People come from bearings within ±this of the robot's front (+x): the front half and the sides [rad]."""
REACH_S_PER_UNIT = 0.4
"""Shortest time per unit of reach [s]: the hand moves at most 0.78 m per unit of reach, so at most
~2.0 m/s (the ISO 13855 hand speed)."""
BEYOND_BUDGET_FRACTION = 0.15
"""Share of the cases with a link delay beyond the gateway's max_data_age_s."""
EXIT_MARGIN_M = 0.5
"""People enter from, and walk out to, this far beyond a side face of the covered volume: their centre is then out
of it, and the trackers no longer report them [m]."""
DEFAULT_COVERAGE = covered_volume(TrackingConfig())
"""The covered volume of a cell without ``[tracking]``."""
ENTER_SPEED_MPS = (1.0, 1.5)
"""Walking speed of a person who walks in to stand (the ``standing`` kind, the collaborative table worker) [m/s]."""

Kind = Literal["approach", "cross", "standing"]
Path = Literal["tracker_to_gateway", "controller_to_gateway", "gateway_to_controller"]
KINDS: tuple[Kind, ...] = ("approach", "cross", "standing")
PATHS: tuple[Path, ...] = ("tracker_to_gateway", "controller_to_gateway", "gateway_to_controller")


@dataclass(frozen=True)
class SweepCase:
    """One generated case: what happens in the cell and how the network behaves.

    Attributes:
        index: number of the case in its sweep.
        seed: seed of the simulation of this case (sensor noise and drops, links, phases).
        scenario: the scripted people.
        trackers: the sensors watching them.
        links: faults of the three paths.
        beyond_budget: True if a delay was drawn beyond the gateway's data age limit.
        params: what was drawn, for the report (kinds, speeds, bearings, delays).
    """

    index: int
    seed: int
    scenario: Scenario
    trackers: dict[str, TrackerConfig]
    links: LinkFaults
    beyond_budget: bool
    params: dict[str, Any]

    def config(self, base: CellConfig) -> CellConfig:
        """``base`` with this case's trackers (validated)."""
        raw = base.model_dump()
        raw["trackers"] = {name: t.model_dump() for name, t in self.trackers.items()}
        return CellConfig.model_validate(raw)


def _heading_to_origin(x_m: float, y_m: float) -> float:
    return math.atan2(-y_m, -x_m)


def _at(bearing_rad: float, distance_m: float) -> tuple[float, float]:
    return distance_m * math.cos(bearing_rad), distance_m * math.sin(bearing_rad)


def beyond_coverage_m(p_xy_m: tuple[float, float], u_xy: tuple[float, float], coverage: Box) -> float:
    """How far from ``p_xy_m`` along the unit floor direction ``u_xy`` a person is :data:`EXIT_MARGIN_M` beyond the
    first side face of ``coverage`` they cross [m] (``p_xy_m`` inside it)."""
    distances = []
    for p, u, lo, hi in zip(p_xy_m, u_xy, coverage.min_m[:2], coverage.max_m[:2], strict=True):
        if abs(u) > 1e-12:
            face = hi + EXIT_MARGIN_M if u > 0.0 else lo - EXIT_MARGIN_M
            distances.append((face - p) / u)
    return max(0.0, min(distances))


def _along(p_xy_m: tuple[float, float], u_xy: tuple[float, float], distance_m: float) -> tuple[float, float]:
    return p_xy_m[0] + distance_m * u_xy[0], p_xy_m[1] + distance_m * u_xy[1]


def _clip_to(human_id: str, both_arms: bool, keyframes: list[Keyframe], duration_s: float) -> HumanScript | None:
    """The script cut at ``duration_s`` (the pose there interpolated), None if it starts too late."""
    script = HumanScript(id=human_id, both_arms=both_arms, keyframes=keyframes)
    if script.start_s >= duration_s - 0.1:
        return None
    if script.end_s <= duration_s:
        return script
    pose = pose_at(script, duration_s)
    if pose is None:  # cannot happen: start_s < duration_s < end_s
        return None
    kept = [k for k in keyframes if k.t_s < duration_s]
    kept.append(Keyframe(t_s=duration_s, xy_m=(pose.x_m, pose.y_m), heading_rad=pose.heading_rad, reach=pose.reach))
    return HumanScript(id=human_id, both_arms=both_arms, keyframes=kept)


def _approach(
    rng: np.random.Generator, human_id: str, duration_s: float, coverage: Box
) -> tuple[HumanScript | None, dict[str, Any]]:
    bearing = float(rng.uniform(-BEARING_LIMIT_RAD, BEARING_LIMIT_RAD))
    stop_m = float(rng.uniform(0.7, 2.0))
    speed = float(rng.uniform(0.8, MAX_SPEED_MPS))
    t0 = float(rng.uniform(0.0, 1.0))
    reach = float(rng.choice([0.0, 1.0, rng.uniform(0.3, 1.0)]))
    both_arms = bool(rng.random() < 0.3)
    reach_time = max(0.1, reach * float(rng.uniform(REACH_S_PER_UNIT, 1.2)))
    hold = float(rng.uniform(0.2, 2.0))
    leave_speed = float(rng.uniform(0.6, MAX_SPEED_MPS))
    outward = (math.cos(bearing), math.sin(bearing))
    start_m = beyond_coverage_m((0.0, 0.0), outward, coverage)  # enters from beyond the boundary, leaves there
    x0, y0 = _at(bearing, start_m)
    x1, y1 = _at(bearing, stop_m)
    facing = _heading_to_origin(x0, y0)
    t = t0
    frames = [Keyframe(t_s=t, xy_m=(x0, y0), heading_rad=facing)]
    t += (start_m - stop_m) / speed
    frames.append(Keyframe(t_s=t, xy_m=(x1, y1), heading_rad=facing))
    if reach > 0.0:
        t += reach_time
        frames.append(Keyframe(t_s=t, xy_m=(x1, y1), heading_rad=facing, reach=reach))
        t += hold
        frames.append(Keyframe(t_s=t, xy_m=(x1, y1), heading_rad=facing, reach=reach))
        t += reach_time
        frames.append(Keyframe(t_s=t, xy_m=(x1, y1), heading_rad=facing))
    else:
        t += hold
        frames.append(Keyframe(t_s=t, xy_m=(x1, y1), heading_rad=facing))
    t += 0.5
    frames.append(Keyframe(t_s=t, xy_m=(x1, y1), heading_rad=facing + math.pi))
    t += (start_m - stop_m) / leave_speed
    frames.append(Keyframe(t_s=t, xy_m=(x0, y0), heading_rad=facing + math.pi))
    params = {
        "kind": "approach",
        "bearing_deg": round(math.degrees(bearing), 1),
        "speed_mps": round(speed, 3),
        "stop_m": round(stop_m, 3),
        "reach": round(reach, 3),
        "both_arms": both_arms,
        "t_start_s": round(t0, 3),
    }
    return _clip_to(human_id, both_arms, frames, duration_s), params


def _cross(
    rng: np.random.Generator, human_id: str, duration_s: float, coverage: Box
) -> tuple[HumanScript | None, dict[str, Any]]:
    offset = float(rng.uniform(0.9, 3.0))  # distance of the walking line from the base
    line_bearing = float(rng.uniform(-math.radians(60.0), math.radians(60.0)))
    speed = float(rng.uniform(0.6, MAX_SPEED_MPS))
    t0 = float(rng.uniform(0.0, 3.0))
    direction = 1.0 if rng.random() < 0.5 else -1.0
    centre = _at(line_bearing, offset)
    along = (-math.sin(line_bearing) * direction, math.cos(line_bearing) * direction)
    start = _along(centre, along, -beyond_coverage_m(centre, (-along[0], -along[1]), coverage))
    end = _along(centre, along, beyond_coverage_m(centre, along, coverage))
    heading = math.atan2(along[1], along[0])
    t1 = t0 + math.dist(start, end) / speed
    frames = [Keyframe(t_s=t0, xy_m=start, heading_rad=heading), Keyframe(t_s=t1, xy_m=end, heading_rad=heading)]
    params = {
        "kind": "cross",
        "bearing_deg": round(math.degrees(line_bearing), 1),
        "offset_m": round(offset, 3),
        "speed_mps": round(speed, 3),
        "t_start_s": round(t0, 3),
    }
    return _clip_to(human_id, False, frames, duration_s), params


def _walk_in(
    rng: np.random.Generator, xy_m: tuple[float, float], t_s: float, coverage: Box
) -> tuple[list[Keyframe], float]:
    """Keyframes of a person walking in from beyond the boundary, from ``t_s``, straight to ``xy_m`` (facing the
    base there); and when they arrive [s]."""
    distance_m = math.hypot(*xy_m)
    outward = (xy_m[0] / distance_m, xy_m[1] / distance_m)
    entry = _along(xy_m, outward, beyond_coverage_m(xy_m, outward, coverage))
    speed = float(rng.uniform(*ENTER_SPEED_MPS))
    facing = _heading_to_origin(*entry)
    arrive_s = t_s + math.dist(entry, xy_m) / speed
    return [Keyframe(t_s=t_s, xy_m=entry, heading_rad=facing)], arrive_s


def _standing(
    rng: np.random.Generator, human_id: str, duration_s: float, coverage: Box
) -> tuple[HumanScript | None, dict[str, Any]]:
    bearing = float(rng.uniform(-BEARING_LIMIT_RAD, BEARING_LIMIT_RAD))
    distance = float(rng.uniform(0.8, 1.8))
    x, y = _at(bearing, distance)
    facing = _heading_to_origin(x, y) + float(rng.uniform(-0.5, 0.5))
    both_arms = bool(rng.random() < 0.3)
    frames, t = _walk_in(rng, (x, y), 0.0, coverage)
    frames.append(Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing))
    arrived_s = t
    reaches = 0
    while True:
        wait = float(rng.uniform(0.5, 3.0))
        reach = float(rng.uniform(0.3, 1.0))
        reach_time = reach * float(rng.uniform(REACH_S_PER_UNIT, 1.2))
        hold = float(rng.uniform(0.0, 1.5))
        if t + wait + 2.0 * reach_time + hold + 0.1 >= duration_s:
            break
        t += wait
        frames.append(Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing))
        t += reach_time
        frames.append(Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing, reach=reach))
        t += hold
        frames.append(Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing, reach=reach))
        t += reach_time
        frames.append(Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing))
        reaches += 1
    if duration_s > t:
        frames.append(Keyframe(t_s=duration_s, xy_m=(x, y), heading_rad=facing))
    params = {
        "kind": "standing",
        "bearing_deg": round(math.degrees(bearing), 1),
        "distance_m": round(distance, 3),
        "arrives_s": round(arrived_s, 3),
        "reaches": reaches,
        "both_arms": both_arms,
    }
    return _clip_to(human_id, both_arms, frames, duration_s), params


def _trackers(rng: np.random.Generator) -> dict[str, TrackerConfig]:
    names = ["front"] if rng.random() < 0.6 else ["front", "side"]
    return {
        name: TrackerConfig(
            rate_hz=float(rng.choice([15.0, 20.0, 30.0, 60.0])),
            noise_std_m=float(rng.uniform(0.0, 0.03)),
            drop_probability=float(rng.choice([0.0, rng.uniform(0.0, 0.2)])),
            latency_s=float(rng.uniform(0.0, 0.06)),
        )
        for name in names
    }


OCCLUSION_STREAM = 17
"""The occlusion of a case is drawn from its own stream (``[seed, index, 17]``): a case with occlusion has the same
people, sensors, links and simulation seed as without, and only its sensors' view differs."""
SENSOR_DISTANCE_M = (2.5, 5.0)
"""Horizontal distance of a sensor from the robot base, on any bearing [m]."""
SENSOR_HEIGHT_M = (2.2, 3.0)
"""Height of a sensor above the floor [m]."""
MISS_PROBABILITY_MAX = 0.05
"""Largest probability that a sensor misses a person in a frame (half the cases: 0)."""
ID_SWAP_PROBABILITY_MAX = 0.01
"""Largest probability per frame that a sensor swaps two people's ids (half the cases: 0)."""
FIXTURE_DISTANCE_M = (0.9, 2.2)
"""Horizontal distance of a fixture (a cabinet, a shelf) from the robot base [m]."""
FIXTURE_TOP_M = (0.9, 1.5)
"""Height of a cabinet's top [m]: it hides legs, or an arm reaching past it."""
HIDING_TOP_M = (1.8, 2.0)
"""Height of a hiding shelf's top [m]: above a person's head, below every sensor (:data:`SENSOR_HEIGHT_M`), so that
it hides a whole person only close behind it (near the robot), never where people enter, at the boundary."""


def with_occlusion(rng: np.random.Generator, trackers: dict[str, TrackerConfig]) -> dict[str, TrackerConfig]:
    """The trackers with line of sight (tracker_emu/occlusion.py): each placed on any bearing around the base,
    :data:`SENSOR_DISTANCE_M` away and :data:`SENSOR_HEIGHT_M` high, missing people and swapping ids now and then."""
    occluding = {}
    for name, tracker in trackers.items():
        bearing = float(rng.uniform(-math.pi, math.pi))
        x_m, y_m = _at(bearing, float(rng.uniform(*SENSOR_DISTANCE_M)))
        occluding[name] = tracker.model_copy(
            update={
                "occlusion": True,
                "position_m": (x_m, y_m, float(rng.uniform(*SENSOR_HEIGHT_M))),
                "miss_probability": float(rng.choice([0.0, rng.uniform(0.0, MISS_PROBABILITY_MAX)])),
                "id_swap_probability": float(rng.choice([0.0, rng.uniform(0.0, ID_SWAP_PROBABILITY_MAX)])),
            }
        )
    return {name: TrackerConfig.model_validate(t.model_dump()) for name, t in occluding.items()}


PERSONS_STREAM = 19
"""The hostile tracking of a case (:func:`with_hostile_tracking`) is drawn from its own stream (``[seed, index, 19]``):
the same people, sensors, links and occlusion as without, plus what it adds."""
COMPANION_GAP_M = (0.4, 2.0)
"""How far behind the first person (farther from the robot's base, on their path) their companion walks [m]: the
first one hidden at the robot, the companion seen (the review's cases 1-3)."""
HIDDEN_AT_M = (0.85, 1.2)
"""Where the hidden person stands, from the robot's base [m]: their reach (1.0) puts a hand near the tool."""
BYSTANDER_BEYOND_M = (1.6, 2.6)
"""How much farther from the base than the hidden person a bystander stands, in view [m]: far enough that the robot
may run at speed beside them, near enough that a rule releasing a lost person by anyone who could have reached their
place releases the hidden one."""
BYSTANDER_BEARING_OFFSET_RAD = (math.radians(15.0), math.radians(40.0))
"""How far round from the hidden person's bearing the bystander stands (either side) [rad]."""
ALONE_WITH_BYSTANDER_SHARE = 0.5
"""Share of the cases with a bystander where the hidden person and the bystander are the only people, hidden from
every sensor and nobody merged or refused: nothing but the release rule then holds the robot (the cases where a rule
releasing the hidden person by the bystander drives the robot into them)."""
STAMP_LATE_S = (0.05, 0.14)
"""How late one tracker stamps its frames [s], within what its data age leaves (:func:`_stamp_late_within`)."""
STAMP_LATE_HEADROOM_SHARE = 0.8
"""The late stamp takes at most this share of what the data age limit leaves beyond the tracker's latency, its
link's worst delay and one frame interval: late, yet fresh enough that the robot works beside it."""


def _companion_behind(
    rng: np.random.Generator, first: HumanScript, duration_s: float
) -> tuple[HumanScript | None, float]:
    """Someone walking the first person's path :data:`COMPANION_GAP_M` farther from the base, and that gap [m]."""
    gap_m = float(rng.uniform(*COMPANION_GAP_M))
    closest = min(first.keyframes, key=lambda k: math.hypot(*k.xy_m))
    norm = math.hypot(*closest.xy_m) or 1.0
    out = (closest.xy_m[0] / norm * gap_m, closest.xy_m[1] / norm * gap_m)
    frames = [k.model_copy(update={"xy_m": (k.xy_m[0] + out[0], k.xy_m[1] + out[1])}) for k in first.keyframes]
    return _clip_to("h9", first.both_arms, frames, duration_s), gap_m


def _hidden_at_the_robot(
    rng: np.random.Generator, trackers: Mapping[str, TrackerConfig], duration_s: float, coverage: Box
) -> tuple[HumanScript | None, list[Fixture], float]:
    """Someone who walks up to the robot (:data:`HIDDEN_AT_M`), reaches toward it for the rest of the case, and
    vanishes there behind a shelf from every sensor that saw them come in; and where they stand [m]."""
    bearing = float(rng.uniform(-BEARING_LIMIT_RAD, BEARING_LIMIT_RAD))
    x, y = _at(bearing, float(rng.uniform(*HIDDEN_AT_M)))
    frames, t = _walk_in(rng, (x, y), 0.0, coverage)
    facing = _heading_to_origin(x, y)
    frames += [
        Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing),
        Keyframe(t_s=t + 0.8, xy_m=(x, y), heading_rad=facing, reach=1.0),
        Keyframe(t_s=max(duration_s, t + 1.0), xy_m=(x, y), heading_rad=facing, reach=1.0),
    ]
    shelves = [
        _hiding_cabinet(rng, (x, y), (t.position_m[0], t.position_m[1]))
        for t in trackers.values()
        if t.position_m is not None and x * t.position_m[0] + y * t.position_m[1] > 0
    ]
    return _clip_to("h8", False, frames, duration_s), shelves, math.hypot(x, y)


def _bystander_beyond(
    rng: np.random.Generator, hidden_xy_m: tuple[float, float], duration_s: float, coverage: Box
) -> tuple[HumanScript | None, float]:
    """Someone who walks in and stands :data:`BYSTANDER_BEYOND_M` farther out than the hidden person, a little round
    from them, for the rest of the case; and how much farther [m]."""
    beyond_m = float(rng.uniform(*BYSTANDER_BEYOND_M))
    offset = float(rng.uniform(*BYSTANDER_BEARING_OFFSET_RAD)) * (1.0 if rng.random() < 0.5 else -1.0)
    bearing = math.atan2(hidden_xy_m[1], hidden_xy_m[0]) + offset
    x, y = _at(bearing, math.hypot(*hidden_xy_m) + beyond_m)
    frames, t = _walk_in(rng, (x, y), float(rng.uniform(0.0, 2.0)), coverage)
    facing = _heading_to_origin(x, y)
    frames += [
        Keyframe(t_s=t, xy_m=(x, y), heading_rad=facing),
        Keyframe(t_s=max(duration_s, t + 1.0), xy_m=(x, y), heading_rad=facing),
    ]
    return _clip_to("bystander", False, frames, duration_s), beyond_m


def _hiding_from_the_rest(
    rng: np.random.Generator, spot: tuple[float, float], trackers: Mapping[str, TrackerConfig]
) -> list[Fixture]:
    """A hiding shelf toward every placed sensor that no shelf stands toward yet (the far side's too): the hidden
    person is then hidden from every sensor once at the robot."""
    return [
        _hiding_cabinet(rng, spot, (t.position_m[0], t.position_m[1]))
        for t in trackers.values()
        if t.position_m is not None and spot[0] * t.position_m[0] + spot[1] * t.position_m[1] <= 0
    ]


def _standing_xy_m(script: HumanScript) -> tuple[float, float]:
    """Where a script ends [m]."""
    return script.keyframes[-1].xy_m


def _stamp_late_within(
    drawn_s: float, tracker: TrackerConfig, latency_s: float, link_worst_s: float, max_data_age_s: float
) -> float:
    """How late a tracker stamps: ``drawn_s``, capped to :data:`STAMP_LATE_HEADROOM_SHARE` of what the data age limit
    leaves beyond its latency, its link's worst delay and one frame interval (never below 0) [s]."""
    headroom_s = max_data_age_s - latency_s - link_worst_s - 1.0 / tracker.rate_hz
    return max(0.0, min(drawn_s, STAMP_LATE_HEADROOM_SHARE * headroom_s))


def _hostile_trackers(
    rng: np.random.Generator, trackers: Mapping[str, TrackerConfig], link_worst_s: float, max_data_age_s: float
) -> dict[str, dict[str, Any]]:
    """Per tracker, what it does wrong: one stamps late (its latency capped, the stamp within its age budget), ids
    renewed, one joining late, now and then one merging people or naming parts by kind."""
    names = sorted(trackers)
    updates: dict[str, dict[str, Any]] = {name: {} for name in names}
    late = names[int(rng.integers(0, len(names)))]
    latency_s = min(trackers[late].latency_s, 0.02)
    updates[late]["stamp_late_s"] = _stamp_late_within(
        float(rng.uniform(*STAMP_LATE_S)), trackers[late], latency_s, link_worst_s, max_data_age_s
    )
    updates[late]["latency_s"] = latency_s
    for name in names:
        updates[name]["id_renew_probability"] = float(rng.choice([0.0, rng.uniform(0.0, 0.02)]))
    if rng.random() < 0.5:
        updates[names[int(rng.integers(0, len(names)))]]["blind_until_s"] = float(rng.uniform(0.5, 4.0))
    if rng.random() < 0.1:
        updates[names[int(rng.integers(0, len(names)))]]["merge_within_m"] = 1.0
    if rng.random() < 0.1:
        updates[names[int(rng.integers(0, len(names)))]]["part_names_by_kind"] = True
    return updates


def _with_bystander(
    own: np.random.Generator,
    hidden: HumanScript,
    humans: list[HumanScript],
    trackers: Mapping[str, TrackerConfig],
    duration_s: float,
    coverage: Box,
    drawn: dict[str, Any],
) -> tuple[list[HumanScript], list[Fixture]]:
    """In half the cases a bystander beyond the hidden person (:func:`_bystander_beyond`), and in
    :data:`ALONE_WITH_BYSTANDER_SHARE` of those only the two of them, the hidden one hidden from every sensor; the
    people and the shelves it adds. Writes what it drew into ``drawn``."""
    if own.random() >= 0.5:
        return humans, []
    bystander, beyond_m = _bystander_beyond(own, _standing_xy_m(hidden), duration_s, coverage)
    if bystander is None:
        return humans, []
    drawn["bystander_beyond_m"] = round(beyond_m, 3)
    if own.random() >= ALONE_WITH_BYSTANDER_SHARE:
        return [*humans, bystander], []
    drawn["alone_with_bystander"] = True
    return [hidden, bystander], _hiding_from_the_rest(own, _standing_xy_m(hidden), trackers)


def with_hostile_tracking(
    rng: np.random.Generator,
    humans: list[HumanScript],
    trackers: dict[str, TrackerConfig],
    duration_s: float,
    coverage: Box = DEFAULT_COVERAGE,
    *,
    link_worst_s: float = 0.0,
    max_data_age_s: float = 0.2,
) -> tuple[list[HumanScript], dict[str, TrackerConfig], list[Fixture], dict[str, Any]]:
    """The cases that broke the release rule before persons (issue 32): a companion walking behind the first person,
    a second tracker where there was one, one tracker stamping late, trackers renewing ids, one joining late, and
    now and then one that merges people or names parts by kind (the door refuses those: the robots stop). In half
    the cases someone walks up to the robot, reaches toward it and vanishes behind shelves there, from every sensor
    that saw them come in (the one who must stay held); in half of those, a bystander stands in view 1.6–2.6 m
    farther out (whom a rule releasing the lost by anyone who could have reached their place takes for them), and in
    half of those again the two are alone, the hidden one hidden from every sensor, nobody merged or refused (the
    cases where such a rule drives the robot into the hidden person). The late tracker's stamps stay within what
    the data age limit leaves beyond its link's worst delay (``link_worst_s``, ``max_data_age_s``).

    Returns:
        The people, the trackers, the hiding shelves and what was drawn (for the case's parameters).
    """
    drawn: dict[str, Any] = {}
    if humans and rng.random() < 0.7:
        companion, gap_m = _companion_behind(rng, humans[0], duration_s)
        if companion is not None:
            humans = [*humans, companion]
            drawn["companion_behind_m"] = round(gap_m, 3)
    trackers = dict(trackers)
    if len(trackers) == 1:
        (only,) = trackers.values()
        bearing = float(rng.uniform(-math.pi, math.pi))
        x_m, y_m = _at(bearing, float(rng.uniform(*SENSOR_DISTANCE_M)))
        position = (x_m, y_m, float(rng.uniform(*SENSOR_HEIGHT_M))) if only.position_m is not None else None
        trackers["side"] = only.model_copy(update={"position_m": position})
    shelves: list[Fixture] = []
    if rng.random() < 0.5:
        hidden, shelves, at_m = _hidden_at_the_robot(rng, trackers, duration_s, coverage)
        if hidden is not None:
            humans = [*humans, hidden]
            drawn["hidden_at_m"] = round(at_m, 3)
            # drawn from a stream of its own, so that every other draw of the case stays as it was
            own = rng.spawn(1)[0]
            humans, more_shelves = _with_bystander(own, hidden, humans, trackers, duration_s, coverage, drawn)
            shelves = [*shelves, *more_shelves]
    updates = _hostile_trackers(rng, trackers, link_worst_s, max_data_age_s)
    if drawn.get("alone_with_bystander"):
        for update in updates.values():  # nobody merged or refused: only the release rule decides what the robot does
            update.pop("merge_within_m", None)
            update.pop("part_names_by_kind", None)
    trackers = {n: TrackerConfig.model_validate(trackers[n].model_dump() | u) for n, u in updates.items()}
    drawn["shelves"] = len(shelves)
    drawn["trackers"] = {
        n: {k: round(v, 4) if isinstance(v, float) else v for k, v in u.items()} for n, u in updates.items()
    }
    return humans, trackers, shelves, drawn


def _spot_xy_m(person: dict[str, Any]) -> tuple[float, float] | None:
    """Where a generated person stops near the robot (from their parameters), None for people who walk past [m]."""
    distance_m = person.get("stop_m", person.get("distance_m"))
    if distance_m is None:
        return None
    return _at(math.radians(person["bearing_deg"]), distance_m)


def _hiding_cabinet(rng: np.random.Generator, spot: tuple[float, float], sensor_xy: tuple[float, float]) -> Fixture:
    """A tall cabinet (a shelf) 0.6–0.9 m from ``spot``, towards the sensor: from that sensor, a person there vanishes
    behind it (:data:`HIDING_TOP_M`)."""
    gap_m = float(rng.uniform(0.6, 0.9))
    length = math.dist(spot, sensor_xy)
    x_m = spot[0] + gap_m * (sensor_xy[0] - spot[0]) / length
    y_m = spot[1] + gap_m * (sensor_xy[1] - spot[1]) / length
    radius_m = float(rng.uniform(0.35, 0.45))
    top_m = float(rng.uniform(*HIDING_TOP_M))
    return Fixture(name="shelf", a_m=(x_m, y_m, radius_m), b_m=(x_m, y_m, top_m - radius_m), radius_m=radius_m)


def occluding_fixtures(
    rng: np.random.Generator, trackers: dict[str, TrackerConfig], people: Sequence[dict[str, Any]]
) -> list[Fixture]:
    """The fixtures of a case with occlusion: upright capsules standing on the floor that hide what lies behind them
    from the sensors with occlusion.

    - In half the cases, a tall shelf between the first sensor and where the first person who stops near the robot
      stops (:func:`_hiding_cabinet`), when that sensor is on their side of the robot, so that it saw them come in:
      from that sensor they vanish behind it beside the robot (with one sensor, the gateway then keeps them as a
      lost track; a gateway that forgets them drives the robot into them).
    - 0–2 cabinets anywhere near the robot (:data:`FIXTURE_DISTANCE_M`, :data:`FIXTURE_TOP_M`).

    They only hide: people's paths do not avoid them (the gateway and the auditor judge people and robots only).
    """
    fixtures = []
    sensor = next(iter(trackers.values())).position_m
    spots = [xy for xy in map(_spot_xy_m, people) if xy is not None]
    if rng.random() < 0.5 and sensor is not None and spots and spots[0][0] * sensor[0] + spots[0][1] * sensor[1] > 0:
        fixtures.append(_hiding_cabinet(rng, spots[0], (sensor[0], sensor[1])))
    for i in range(int(rng.integers(0, 3))):
        x_m, y_m = _at(float(rng.uniform(-math.pi, math.pi)), float(rng.uniform(*FIXTURE_DISTANCE_M)))
        radius_m = float(rng.uniform(0.25, 0.4))
        top_m = float(rng.uniform(*FIXTURE_TOP_M))
        floor, top = (x_m, y_m, radius_m), (x_m, y_m, top_m - radius_m)
        fixtures.append(Fixture(name=f"cabinet{i + 1}", a_m=floor, b_m=top, radius_m=radius_m))
    return fixtures


def _path_fault(rng: np.random.Generator, budget_s: float) -> LinkFault:
    """A fault whose worst delay (delay + jitter) stays within ``budget_s``."""
    total = float(rng.uniform(0.0, budget_s))
    jitter = float(rng.uniform(0.0, min(0.03, total)))
    return LinkFault(
        delay_s=total - jitter,
        jitter_s=jitter,
        loss=float(rng.choice([0.0, rng.uniform(0.0, 0.1)])),
        duplication=float(rng.choice([0.0, rng.uniform(0.0, 0.1)])),
    )


def _links(
    rng: np.random.Generator, trackers: dict[str, TrackerConfig], max_data_age_s: float, watchdog_s: float
) -> tuple[LinkFaults, bool, Path | None]:
    """Faults of the three paths: within the data age budget, or (sometimes) one path beyond it.

    Within budget: the human data's age (sensor latency + link) and the override round trip
    (gateway → controller → gateway) each stay below ``max_data_age_s``; the override path alone stays
    below the controller's watchdog.
    """
    latency = max(t.latency_s for t in trackers.values())
    round_trip_budget = 0.8 * max_data_age_s
    override_budget = min(0.8 * watchdog_s, 0.5 * round_trip_budget)
    faults = {
        "tracker_to_gateway": _path_fault(rng, max(0.0, 0.7 * max_data_age_s - latency)),
        "gateway_to_controller": _path_fault(rng, override_budget),
        "controller_to_gateway": _path_fault(rng, round_trip_budget - override_budget),
    }
    beyond: Path | None = None
    if rng.random() < BEYOND_BUDGET_FRACTION:
        beyond = PATHS[int(rng.integers(0, len(PATHS)))]
        base = faults[beyond]
        faults[beyond] = LinkFault(
            delay_s=float(rng.uniform(1.05, 2.0)) * max_data_age_s,
            jitter_s=base.jitter_s,
            loss=base.loss,
            duplication=base.duplication,
        )
    return LinkFaults(**faults), beyond is not None, beyond


def generate_case(
    sweep_seed: int,
    index: int,
    duration_s: float,
    max_data_age_s: float,
    watchdog_s: float = 0.1,
    *,
    coverage: Box = DEFAULT_COVERAGE,
    occlusion: bool = False,
    hostile_tracking: bool = False,
) -> SweepCase:
    """Case number ``index`` of the sweep seeded ``sweep_seed`` (the same numbers give the same case).

    Args:
        sweep_seed: seed of the sweep.
        index: number of the case.
        duration_s: length of the scenario (and of the run) [s].
        max_data_age_s: the gateway's data age limit, the budget of the link delays [s].
        watchdog_s: the controller's override watchdog [s].
        coverage: the volume the trackers cover (people enter and leave through its side faces) [m].
        occlusion: the trackers see with line of sight (:func:`with_occlusion`, drawn from the case's own stream).
        hostile_tracking: the cases that broke the release rule before persons (:func:`with_hostile_tracking`, drawn
            from its own stream, after the occlusion).
    """
    rng = np.random.default_rng([sweep_seed, index])
    people = int(rng.choice([1, 1, 2, 3]))
    humans: list[HumanScript] = []
    people_params: list[dict[str, Any]] = []
    makers = {"approach": _approach, "cross": _cross, "standing": _standing}
    for i in range(people):
        kind: Kind = KINDS[int(rng.choice([0, 0, 1, 2]))] if i else "approach"
        script, person = makers[kind](rng, f"h{i + 1}", duration_s, coverage)
        if script is not None:
            humans.append(script)
            people_params.append(person)
    trackers = _trackers(rng)
    links, beyond, beyond_path = _links(rng, trackers, max_data_age_s, watchdog_s)
    fixtures: list[Fixture] = []
    if occlusion:
        occlusion_rng = np.random.default_rng([sweep_seed, index, OCCLUSION_STREAM])
        trackers = with_occlusion(occlusion_rng, trackers)
        fixtures = occluding_fixtures(occlusion_rng, trackers, people_params)
    hostile: dict[str, Any] = {}
    if hostile_tracking:
        hostile_rng = np.random.default_rng([sweep_seed, index, PERSONS_STREAM])
        tracker_link = links.tracker_to_gateway
        humans, trackers, shelves, hostile = with_hostile_tracking(
            hostile_rng,
            humans,
            trackers,
            duration_s,
            coverage,
            link_worst_s=tracker_link.delay_s + tracker_link.jitter_s,
            max_data_age_s=max_data_age_s,
        )
        fixtures = [*fixtures, *shelves]
    scenario = Scenario(
        description=f"generated case {index} of sweep {sweep_seed}",
        duration_s=duration_s,
        loop=False,
        humans=humans,
        fixtures=fixtures,
    )
    params: dict[str, Any] = {
        "people": people_params,
        "trackers": {n: t.model_dump() for n, t in trackers.items()},
        "links": {path: {k: round(v, 4) for k, v in vars(getattr(links, path)).items()} for path in PATHS},
        "beyond_budget": beyond_path,
        "fixtures": [f.model_dump() for f in fixtures],
    }
    if hostile_tracking:
        params["hostile_tracking"] = hostile
    return SweepCase(
        index=index,
        seed=int(rng.integers(0, 2**31 - 1)),
        scenario=scenario,
        trackers=trackers,
        links=links,
        beyond_budget=beyond,
        params=params,
    )


# -- the collaborative-station suite (issue 10) ---------------------------------------------------------

COLLABORATIVE_KINDS = ("shared_table", "walk_by", "reach_in", "stand_in_path")
"""Kinds of collaborative case, in turn by case number: a worker at a table shared with the robot (handovers every
few seconds); the same worker and a second person walking by at 1–3 m; a person who walks up and reaches into the
robot's path; a person who stands in the robot's path for a while and leaves."""
COLLABORATIVE_SPEED_MPS = 1.5
"""Fastest walk of a collaborative case: people at a station walk, within the configured K = 1.6 m/s [m/s]."""
PICK_BEARING_RAD = math.atan2(-0.35, 0.45)
"""Bearing of the program's pick point from the base (configs/programs/ur5_pick_place.toml) [rad]."""
PLACE_BEARING_RAD = math.atan2(0.30, 0.60)
"""Bearing of the program's place point [rad]."""


def _handovers(
    rng: np.random.Generator, frames: list[Keyframe], t_s: float, end_s: float, xy: tuple[float, float], facing: float
) -> int:
    """Append reach-in / hold / withdraw keyframes every 2–5 s from ``t_s`` until ``end_s``; how many."""
    count = 0
    while True:
        wait = float(rng.uniform(2.0, 5.0))
        reach = float(rng.uniform(0.5, 1.0))
        reach_time = reach * float(rng.uniform(REACH_S_PER_UNIT, 1.0))
        hold = float(rng.uniform(0.3, 1.0))
        if t_s + wait + 2.0 * reach_time + hold + 0.1 >= end_s:
            return count
        t_s += wait
        frames.append(Keyframe(t_s=t_s, xy_m=xy, heading_rad=facing))
        t_s += reach_time
        frames.append(Keyframe(t_s=t_s, xy_m=xy, heading_rad=facing, reach=reach))
        t_s += hold
        frames.append(Keyframe(t_s=t_s, xy_m=xy, heading_rad=facing, reach=reach))
        t_s += reach_time
        frames.append(Keyframe(t_s=t_s, xy_m=xy, heading_rad=facing))
        count += 1


def _table_worker(
    rng: np.random.Generator, human_id: str, duration_s: float, coverage: Box
) -> tuple[HumanScript | None, dict[str, Any]]:
    """Walks in from beyond the boundary at the start of the run and works across a table from the robot, 1.4–1.8 m
    from its base (0.6–1.0 m from the robot's surface: the program's tool reaches x = 0.64 m; the worker's arm
    reaches into the robot's workspace), taking or handing over a part every 2–5 s."""
    bearing = float(rng.uniform(-0.5, 0.5))
    distance = float(rng.uniform(1.4, 1.8))
    xy = _at(bearing, distance)
    facing = _heading_to_origin(*xy)
    frames, arrive_s = _walk_in(rng, xy, 0.0, coverage)
    frames.append(Keyframe(t_s=arrive_s, xy_m=xy, heading_rad=facing))
    count = _handovers(rng, frames, arrive_s, duration_s, xy, facing)
    if duration_s > frames[-1].t_s:
        frames.append(Keyframe(t_s=duration_s, xy_m=xy, heading_rad=facing))
    params = {
        "kind": "shared_table",
        "bearing_deg": round(math.degrees(bearing), 1),
        "distance_m": round(distance, 3),
        "arrives_s": round(arrive_s, 3),
    }
    return _clip_to(human_id, False, frames, duration_s), {**params, "handovers": count}


def _walk_by(
    rng: np.random.Generator, human_id: str, duration_s: float, coverage: Box
) -> tuple[HumanScript | None, dict[str, Any]]:
    """Walks past the station on a line 1–3 m from the base, at 0.8–1.5 m/s, behind or beside the robot, from one
    side of the boundary to the other."""
    offset = float(rng.uniform(1.0, 3.0))
    line_bearing = float(rng.choice([math.pi, math.pi / 2, -math.pi / 2])) + float(rng.uniform(-0.3, 0.3))
    speed = float(rng.uniform(0.8, COLLABORATIVE_SPEED_MPS))
    t0 = float(rng.uniform(0.0, 0.3 * duration_s))
    centre = _at(line_bearing, offset)
    along = (-math.sin(line_bearing), math.cos(line_bearing))
    start = _along(centre, along, -beyond_coverage_m(centre, (-along[0], -along[1]), coverage))
    end = _along(centre, along, beyond_coverage_m(centre, along, coverage))
    heading = math.atan2(along[1], along[0])
    frames = [
        Keyframe(t_s=t0, xy_m=start, heading_rad=heading),
        Keyframe(t_s=t0 + math.dist(start, end) / speed, xy_m=end, heading_rad=heading),
    ]
    params = {"kind": "walk_by", "offset_m": round(offset, 3), "speed_mps": round(speed, 3), "t_start_s": round(t0, 3)}
    return _clip_to(human_id, False, frames, duration_s), params


def _visit(
    rng: np.random.Generator, human_id: str, duration_s: float, kind: str, coverage: Box
) -> tuple[HumanScript | None, dict[str, Any]]:
    """Walks in from beyond the boundary to the robot's pick or place side and back out: ``reach_in`` stops 0.9–1.2 m
    from the base and reaches into the path twice; ``stand_in_path`` stops 0.6–0.9 m from it and stands 3–8 s."""
    bearing = float(rng.choice([PICK_BEARING_RAD, PLACE_BEARING_RAD])) + float(rng.uniform(-0.2, 0.2))
    start_m = beyond_coverage_m((0.0, 0.0), (math.cos(bearing), math.sin(bearing)), coverage)
    speed = float(rng.uniform(0.8, COLLABORATIVE_SPEED_MPS))
    stop_m = float(rng.uniform(0.9, 1.2) if kind == "reach_in" else rng.uniform(0.6, 0.9))
    x0y0, x1y1 = _at(bearing, start_m), _at(bearing, stop_m)
    facing = _heading_to_origin(*x0y0)
    t = float(rng.uniform(0.0, 1.5))
    frames = [Keyframe(t_s=t, xy_m=x0y0, heading_rad=facing)]
    t += (start_m - stop_m) / speed
    frames.append(Keyframe(t_s=t, xy_m=x1y1, heading_rad=facing))
    stay = float(rng.uniform(3.0, 8.0))
    if kind == "reach_in":
        _handovers(rng, frames, t, t + stay, x1y1, facing)
    frames.append(Keyframe(t_s=t + stay, xy_m=x1y1, heading_rad=facing))
    frames.append(Keyframe(t_s=t + stay + 0.5, xy_m=x1y1, heading_rad=facing + math.pi))
    frames.append(Keyframe(t_s=t + stay + 0.5 + (start_m - stop_m) / speed, xy_m=x0y0, heading_rad=facing + math.pi))
    params = {"kind": kind, "bearing_deg": round(math.degrees(bearing), 1), "stop_m": round(stop_m, 3)}
    return _clip_to(human_id, False, frames, duration_s), {
        **params,
        "speed_mps": round(speed, 3),
        "stay_s": round(stay, 3),
    }


def _collaborative_people(
    rng: np.random.Generator, kind: str, duration_s: float, coverage: Box
) -> tuple[list[HumanScript], list[dict[str, Any]]]:
    people: list[tuple[HumanScript | None, dict[str, Any]]]
    if kind in ("shared_table", "walk_by"):
        people = [_table_worker(rng, "h1", duration_s, coverage)]
        if kind == "walk_by":
            people.append(_walk_by(rng, "h2", duration_s, coverage))
    else:
        people = [_visit(rng, "h1", duration_s, kind, coverage)]
    kept = [(s, p) for s, p in people if s is not None]
    return [s for s, _ in kept], [p for _, p in kept]


def generate_collaborative_case(
    suite_seed: int,
    index: int,
    duration_s: float,
    max_data_age_s: float,
    watchdog_s: float = 0.1,
    *,
    coverage: Box = DEFAULT_COVERAGE,
    occlusion: bool = False,
) -> SweepCase:
    """Case ``index`` of the collaborative-station suite ``suite_seed`` (kind :data:`COLLABORATIVE_KINDS` in turn).

    Sensors as in the stress suite (``occlusion``: with line of sight, drawn from the case's own stream); link delays
    always within the gateway's data age budget (a station's network is not the subject here: the stress suite covers
    delays beyond it). People enter and leave through the side faces of ``coverage`` [m].
    """
    rng = np.random.default_rng([suite_seed, index, 10])
    kind = COLLABORATIVE_KINDS[index % len(COLLABORATIVE_KINDS)]
    humans, people = _collaborative_people(rng, kind, duration_s, coverage)
    trackers = _trackers(rng)
    latency = max(t.latency_s for t in trackers.values())
    round_trip_budget = 0.8 * max_data_age_s
    override_budget = min(0.8 * watchdog_s, 0.5 * round_trip_budget)
    links = LinkFaults(
        tracker_to_gateway=_path_fault(rng, max(0.0, 0.7 * max_data_age_s - latency)),
        gateway_to_controller=_path_fault(rng, override_budget),
        controller_to_gateway=_path_fault(rng, round_trip_budget - override_budget),
    )
    fixtures: list[Fixture] = []
    if occlusion:
        occlusion_rng = np.random.default_rng([suite_seed, index, 10, OCCLUSION_STREAM])
        trackers = with_occlusion(occlusion_rng, trackers)
        fixtures = occluding_fixtures(occlusion_rng, trackers, people)
    scenario = Scenario(
        description=f"collaborative case {index} ({kind}) of suite {suite_seed}",
        duration_s=duration_s,
        loop=False,
        humans=humans,
        fixtures=fixtures,
    )
    params: dict[str, Any] = {
        "kind": kind,
        "people": people,
        "trackers": {n: t.model_dump() for n, t in trackers.items()},
        "links": {path: {k: round(v, 4) for k, v in vars(getattr(links, path)).items()} for path in PATHS},
        "beyond_budget": None,
        "fixtures": [f.model_dump() for f in fixtures],
    }
    seed = int(rng.integers(0, 2**31 - 1))
    return SweepCase(index, seed, scenario, trackers, links, False, params)


def case_of_cell(
    config: CellConfig,
    suite_seed: int,
    index: int,
    duration_s: float,
    *,
    collaborative: bool = False,
    occlusion: bool = False,
    hostile_tracking: bool = False,
) -> SweepCase:
    """Case ``index`` of a suite for the cell ``config``: its data-age limit, its controllers' shortest watchdog and
    its covered volume (the stress suite of the sweep, or the collaborative one; trackers with line of sight if
    ``occlusion``; the stress suite's hostile tracking if ``hostile_tracking``)."""
    watchdog_s = min(r.controller.watchdog_s for r in config.robots.values())
    coverage = covered_volume(config.tracking)
    max_age_s = config.safety.max_data_age_s
    if collaborative:
        return generate_collaborative_case(
            suite_seed, index, duration_s, max_age_s, watchdog_s, coverage=coverage, occlusion=occlusion
        )
    return generate_case(
        suite_seed,
        index,
        duration_s,
        max_age_s,
        watchdog_s,
        coverage=coverage,
        occlusion=occlusion,
        hostile_tracking=hostile_tracking,
    )
