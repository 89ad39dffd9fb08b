"""People as persons made of tracks: a person no longer seen is *lost*, never gone (docs/contract.md "Tracks",
docs/safety-math.md §11).

Separation monitoring rests on one assumption: people move at most at K. Someone no longer reported (hidden by the
robot or by another person, a missed detection, a tracker glitch) is somewhere within ``K · (time since last seen)``
of where they were last seen, so the gateway keeps them.

- A **track** is one tracker's view of one body, frame after frame: a detection continues its tracker's *seen*
  track of the same id only when it covers that track's last body (:func:`gateway.bodies.covers`: one detected
  part per part the track had, within the tracker's frame-to-frame reach). Anything else (a new id, a missing part,
  a jump, a track that was lost) starts a new track: a lost track is never continued by an id.
- A **person** is the tracks of all trackers that are one body. A new track joins the one person whose bodies it
  could be (:func:`gateway.bodies.near`, gated by K between the stamps), when exactly one is near it and it did not
  appear where people enter; with none near it, or several, or at the boundary, it is a new person (ambiguity keeps
  more people). A track that comes near another person's seen track is taken out of its person (it may have swapped
  bodies with them there), unless both persons have no lost tracks and no tracker sees both (then they are one body
  and join).
- A lost track is **released** only by
  (a) *redetected*: a seen track **of the same person**, captured after it was lost, covers its last body (each lost
      part inside its own part of the detection grown by ``K_reach · Δt`` and the trackers' noise), and is near no
      lost track of another person;
  (b) *left*: every capsule of its last body lay in the exit band of one side face of the covered volume (in an
      exit zone where the cell declares them), its centre moving out through that face;
  (c) *reset*: an operator, after checking the area, released it with an authenticated command.
  Never by a timeout, an id or a name.

Pure: no I/O, no clock; every time is passed in (monotonic [ns]).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.bodies import check_within, covers, near, random_capsules, within
from gateway.kernels import BodyBoxes, RowBoxes, frame_bodies, moved_within, others_maybe_near, slices_near
from hrc_contract.config import NOISE_SIGMAS, CellConfig, ConfigError, TrackingConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules, human_starts, merge_humans

FloatArray = npt.NDArray[np.float64]
NS_PER_S = 1_000_000_000

MAX_LIVE_TRACKS = 1024
"""More seen + lost tracks than this is a fault (``tracks_overflow``, δ = 0): a hostile tracker inventing people
must not make the gateway's memory or cycle time grow without bound."""
RELEASED_KEPT = 32
"""Released tracks shown in the status (the newest), for the operator to see what released whom."""
VELOCITY_WINDOW_NS = 400_000_000
"""A track's centre over this window gives its velocity for the exit rule [ns]."""
CENTRE_SAMPLE_NS = 50_000_000
"""A track's centre is remembered at most this often, its newest always [ns]."""
VELOCITY_MIN_SPAN_NS = 60_000_000
"""At least this span of observations is needed to call a track 'moving out' [ns]."""
REAPPEAR_MAX_S = 0.25
"""A track its tracker lost at most this long ago [s] is continued at the entry band by a detection of the same id
inside its body grown by the motion meanwhile (:meth:`TrackSet._fragment_of`)."""
JOIN_DT_MAX_S = 0.05
"""Two trackers' views join one person only when they agree within the margin and what a person moves in this long
[s]: a late tracker's stamps must not make a neighbour 'the same body' (issue 32, case 3)."""


class TrackState(StrEnum):
    SEEN = "seen"
    LOST = "lost"
    RELEASED = "released"


class ReleaseCause(StrEnum):
    REDETECTED = "redetected"
    LEFT = "left"
    RESET = "reset"
    FORGOTTEN = "forgotten_unsafe_test_only"


class TrackEvent(NamedTuple):
    """A change of a track's state, for the event log: ``kind`` is ``track_lost`` or ``track_released``."""

    kind: str
    track: str
    message: str
    cause: str | None = None


class TrackRecord(NamedTuple):
    """What the status shows of one track, without the time (the status computes ages at its decision's time).

    Attributes:
        label: ``<tracker>/<id>`` (``#<serial>`` appended when another live track has that label).
        tracker: the tracker that saw it.
        human: the human id its capsules carry in the decisions' closest pair: ``<tracker>/<id>`` while seen,
            ``<label> (lost)`` while lost.
        state: seen, lost or released.
        last_seen_mono_ns: when it was last seen (capture time, gateway's monotonic clock) [ns]; None while seen
            (then: its tracker's newest frame), so that the records change only when a track changes state.
        capsules: its capsule count.
        released_by: for a released track, what released it.
        person: the person it belongs to (``P<n>``).
        held_because: lost: why no detection released it yet, when one could have been them.
    """

    label: str
    tracker: str
    human: str
    state: TrackState
    last_seen_mono_ns: int | None
    capsules: int
    released_by: str | None = None
    person: str = ""
    held_because: str | None = None


@dataclass(eq=False)
class Person:
    """The tracks (of any trackers) that are one body; lost tracks stay with their person until released."""

    serial: int
    tracks: list[Track] = field(default_factory=list)
    held_because: str | None = None
    """Why a detection that could have been this person did not release them (shown to the operator)."""

    @property
    def label(self) -> str:
        return f"P{self.serial}"

    def has_lost(self) -> bool:
        return any(t.state is TrackState.LOST for t in self.tracks)


@dataclass(eq=False)
class Track:
    """One tracker's view of one body; its capsules are a slice of the frame it was last seen in."""

    serial: int
    label: str
    tracker: str
    human_id: str
    frame: HumanCapsules
    start: int
    end: int
    last_seen_mono_ns: int
    person: Person
    state: TrackState = TrackState.SEEN
    centres: deque[tuple[int, FloatArray]] = field(default_factory=lambda: deque(maxlen=64))
    released_by: str | None = None
    released_mono_ns: int = 0
    last_centre: FloatArray | None = None
    box_lo_m: FloatArray = field(default_factory=lambda: np.zeros(3))
    """Lower corner of the box around its last capsules' end points [m] (with ``box_hi_m`` and ``radius_max_m``: a
    cheap first test of which bodies could be near)."""
    box_hi_m: FloatArray = field(default_factory=lambda: np.zeros(3))
    radius_max_m: float = 0.0
    _capsules: HumanCapsules | None = None

    @property
    def capsules(self) -> HumanCapsules:
        """The capsules it was last seen with (human ids ``<tracker>/<id>``)."""
        if self._capsules is None:
            self._capsules = part(self.frame, self.start, self.end)
        return self._capsules

    @property
    def n_capsules(self) -> int:
        return self.end - self.start

    def observe(
        self,
        frame: HumanCapsules,
        start: int,
        end: int,
        captured_ns: int,
        centre_m: FloatArray,
        box: tuple[FloatArray, FloatArray, float],
    ) -> None:
        """Seen in ``frame[start:end]``, captured at ``captured_ns``, its centre at ``centre_m`` [m], its capsules'
        end points in the box ``(lower, upper corner [m], largest radius [m])``."""
        self.frame, self.start, self.end, self._capsules = frame, start, end, None
        self.last_seen_mono_ns = captured_ns
        self.state = TrackState.SEEN
        self.last_centre = centre_m
        self.box_lo_m, self.box_hi_m, self.radius_max_m = box
        centres = self.centres
        if not centres or captured_ns - centres[-1][0] >= CENTRE_SAMPLE_NS:
            centres.append((captured_ns, centre_m))
            if captured_ns - centres[0][0] > VELOCITY_WINDOW_NS:
                centres.popleft()


def centre(capsules: HumanCapsules) -> FloatArray:
    """Mean of all capsule end points [m]."""
    return np.concatenate((capsules.h_a_world, capsules.h_b_world)).mean(axis=0)  # type: ignore[no-any-return]


def part(capsules: HumanCapsules, start: int, end: int) -> HumanCapsules:
    """Capsules ``start:end`` of a frame, copied into contiguous arrays once (the compiled body tests take them as
    they are, for every pair of people whose boxes may nest)."""
    c = capsules
    return HumanCapsules(
        np.array(c.h_a_world[start:end], dtype=np.float64),
        np.array(c.h_b_world[start:end], dtype=np.float64),
        np.array(c.radius_m[start:end], dtype=np.float64),
        c.human_ids[start:end],
        c.capsule_names[start:end],
    )


def _bodies_in_frames(
    tracks: Sequence[Track],
) -> tuple[HumanCapsules, npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """The tracks' last bodies as slices ``starts[j]:ends[j]`` of their frames' capsules joined once: the seen tracks
    of a tracker share its newest frame, so a frame's people need no copy each (the frames are joined only when the
    tracks come from several; a track's frame holds its capsules, so none is empty)."""
    at: dict[int, int] = {}
    frames: list[HumanCapsules] = []
    offsets: list[int] = []
    total = 0
    for t in tracks:
        offset = at.get(id(t.frame))
        if offset is None:
            offset = at[id(t.frame)] = total
            frames.append(t.frame)
            total += t.frame.n_capsules
        offsets.append(offset)
    starts = np.array([o + t.start for o, t in zip(offsets, tracks, strict=True)], dtype=np.int64)
    ends = np.array([o + t.end for o, t in zip(offsets, tracks, strict=True)], dtype=np.int64)
    return merge_humans(frames), starts, ends  # one frame: itself, read where it is


def reach_speed_mps(config: CellConfig) -> float:
    """How fast a lost person's possible positions grow: ISO 13855's close-range speed where configured, else K."""
    safety = config.safety
    return safety.human_speed_close_mps if safety.close_speed_below_m > 0.0 else safety.human_speed_mps


def _in_exit_zones(points_m: FloatArray, tracking: TrackingConfig) -> npt.NDArray[np.bool_]:
    """Per point: inside one of the cell's exit zones (every point, when it declares none)."""
    if not tracking.exit_zones:
        return np.ones(len(points_m), dtype=bool)
    inside = np.zeros(len(points_m), dtype=bool)
    for zone in tracking.exit_zones:
        inside |= ((points_m >= np.asarray(zone.min_m)) & (points_m <= np.asarray(zone.max_m))).all(axis=1)
    return inside


def _end_points(capsules: HumanCapsules) -> FloatArray:
    return np.concatenate((capsules.h_a_world, capsules.h_b_world))


def touches_entry_band(capsules: HumanCapsules, tracking: TrackingConfig) -> bool:
    """Whether any end point lies where people enter the covered volume: within ``exit_band_m`` of a side face (inside
    an exit zone where the cell declares them), or outside the volume. A body that appears there may have come in."""
    points = _end_points(capsules)
    low, high = np.asarray(tracking.coverage_min_m), np.asarray(tracking.coverage_max_m)
    band = ((points[:, :2] - low[:2] <= tracking.exit_band_m) | (high[:2] - points[:, :2] <= tracking.exit_band_m)).any(
        axis=1
    )
    return bool((band & _in_exit_zones(points, tracking)).any())


def leaving_face(track: Track, tracking: TrackingConfig) -> str | None:
    """The side face of the covered volume through which a track was last seen leaving, or None.

    Every end point of its last capsules lies within ``exit_band_m`` of the face or beyond it (and in an exit zone
    where the cell declares them), and its centre moved out through that face at ``exit_speed_min_mps`` or more over
    its last observations. A hand left at the tool keeps a body from having left, whatever its centre does.
    """
    if not track.centres or track.last_centre is None:
        return None
    (t0_ns, c0), (t1_ns, c1) = track.centres[0], (track.last_seen_mono_ns, track.last_centre)
    span_ns = t1_ns - t0_ns
    if span_ns < VELOCITY_MIN_SPAN_NS:
        return None
    velocity = (c1 - c0) / (span_ns / NS_PER_S)
    points = _end_points(track.capsules)
    if not _in_exit_zones(points, tracking).all():
        return None
    low, high = tracking.coverage_min_m, tracking.coverage_max_m
    band = tracking.exit_band_m
    for axis, name in ((0, "x"), (1, "y")):
        if (points[:, axis] - low[axis] <= band).all() and -velocity[axis] >= tracking.exit_speed_min_mps:
            return f"-{name}"
        if (high[axis] - points[:, axis] <= band).all() and velocity[axis] >= tracking.exit_speed_min_mps:
            return f"+{name}"
    return None


class TrackSet:
    """Every person the cell's trackers reported, as tracks grouped into persons, seen or lost, and the tracks
    recently released.

    Args:
        config: the cell (``tracking``, K, the trackers' noise).
        release_by_id_unsafe: TEST ONLY (default: ``tracking.unsafe_release_by_id_for_tests``): the rule replaced
            by persons (issue 32): a lost track is continued by its tracker's same id within reach, and any detection
            away from the entry band that covers it releases it, whoever it belongs to. The sweep's teeth.
    """

    def __init__(self, config: CellConfig, *, release_by_id_unsafe: bool | None = None) -> None:
        check_within()  # the compiled body test, held to its reference and compiled before the first frame
        check_frame_kernels()  # and the frame path's
        self.tracking = config.tracking
        self.reach_speed_mps = reach_speed_mps(config)
        self._noise_m = {name: NOISE_SIGMAS * t.noise_std_m for name, t in config.trackers.items()}
        self._forget = config.tracking.unsafe_forget_lost_for_tests
        self._by_id = (
            config.tracking.unsafe_release_by_id_for_tests if release_by_id_unsafe is None else release_by_id_unsafe
        )
        self.live: list[Track] = []
        self._table = _BoxTable()
        self._lost: list[Track] = []
        self._previous: dict[str, _Previous] = {}
        self.released: deque[Track] = deque(maxlen=RELEASED_KEPT)
        self._serial = 0
        self._person_serial = 0
        self._frames: dict[str, object] = {}
        self._lost_cache: tuple[int, HumanCapsules] | None = None
        self._records: tuple[TrackRecord, ...] | None = None

    # -- updates ------------------------------------------------------------------------------------------

    def update(
        self, frames: Mapping[str, tuple[object, HumanCapsules, int, Sequence[int] | None] | None], now_mono_ns: int
    ) -> list[TrackEvent]:
        """Take every tracker frame that is new since the last call.

        Args:
            frames: per tracker, ``(identity, capsules, captured_mono_ns, starts)`` of its newest valid frame (the
                identity tells a new frame from the one already taken; ``starts``: :func:`human_starts` of the
                capsules where the door has them, else None), or None without one.
            now_mono_ns: the decision time [ns].

        Returns:
            The tracks' changes (lost, released), in order.
        """
        events: list[TrackEvent] = []
        observed: list[Track] = []
        for tracker, frame in frames.items():
            if frame is None or self._frames.get(tracker) is frame[0]:
                continue
            self._frames[tracker] = frame[0]
            taken, tracks = self._take_frame(tracker, frame[1], frame[2], frame[3])
            events += taken
            observed += tracks
        if observed:
            self._regroup(observed)
        if self._lost and observed:
            events += self._release_redetected()
        if events:
            self._lost_cache = None
            self._records = None
        if self._forget:
            events += self._release_all_lost(now_mono_ns, ReleaseCause.FORGOTTEN, "forgotten (UNSAFE, test only)")
        return events

    def reset(self, which: str, operator: str, now_mono_ns: int) -> list[TrackEvent]:
        """An operator's reset: release the lost track labelled ``which`` (``*``: every lost track).

        Returns:
            The releases; none when no lost track has that label (a seen person cannot be reset: they are there).
        """
        targets = [t for t in self._lost if which in ("*", t.label)]
        events = [self._release(t, now_mono_ns, ReleaseCause.RESET, f"reset by operator {operator!r}") for t in targets]
        if events:
            self._lost_cache = None
            self._records = None
        return events

    def _take_frame(
        self, tracker: str, capsules: HumanCapsules, captured_ns: int, known_starts: Sequence[int] | None = None
    ) -> tuple[list[TrackEvent], list[Track]]:
        """Continue this tracker's seen tracks with the frame's detections; lose the rest; start new tracks.

        The common case, the same people with the same parts as in this tracker's previous frame, is decided for the
        whole frame at once (:func:`moved_within`); any other detection by :func:`gateway.bodies.covers`.

        Returns:
            The changes, and the tracks of the frame's people (continued or new), in the frame's order.
        """
        margin_m = self._margin_m(tracker, tracker)
        previous = self._previous.get(tracker)
        starts = human_starts(capsules) if known_starts is None else list(known_starts)
        starts_array = np.array(starts, dtype=np.int64)
        prefix = len(tracker) + 1
        continued: list[Track | None] = (
            [None] * (len(starts) - 1) if previous is None else _same_people(previous, capsules)
        )
        centres, box_lo, box_hi, box_r = frame_bodies(capsules, starts_array)
        if previous is not None and any(t is not None for t in continued):
            dt_s = (captured_ns - previous.captured_ns) / NS_PER_S
            ok = moved_within(previous.capsules, capsules, starts_array, self.reach_speed_mps * dt_s + margin_m)
            continued = [t if t is not None and ok[k] else None for k, t in enumerate(continued)]
        taken: set[int] = {t.serial for t in continued if t is not None}
        for k, (start, end) in enumerate(itertools.pairwise(starts)):
            if continued[k] is None:
                track = self._continue(
                    tracker,
                    capsules.human_ids[start][prefix:],
                    part(capsules, start, end),
                    taken,
                    margin_m,
                    captured_ns,
                )
                if track is not None:
                    taken.add(track.serial)
                    continued[k] = track
        events: list[TrackEvent] = []
        for track in self._seen_of(tracker):
            if track.serial not in taken:
                events += self._lose(track, captured_ns)
        order: list[Track] = []
        in_table = 0  # the frame's tracks before this one are in the table (a new track's neighbours are read there)
        for k, (start, end) in enumerate(itertools.pairwise(starts)):
            track = continued[k]
            if track is None:
                self._table.set_seen(order[in_table:], box_lo[in_table:k], box_hi[in_table:k], box_r[in_table:k])
                in_table = k
                track = self._new_track(tracker, capsules.human_ids[start][prefix:], capsules, start, end, captured_ns)
            track.observe(capsules, start, end, captured_ns, centres[k], (box_lo[k], box_hi[k], float(box_r[k])))
            order.append(track)
        self._table.set_seen(order[in_table:], box_lo[in_table:], box_hi[in_table:], box_r[in_table:])
        self._previous[tracker] = _Previous(capsules, captured_ns, tuple(order))
        return events, order

    def _seen_of(self, tracker: str) -> list[Track]:
        previous = self._previous.get(tracker)
        if previous is None:
            return []
        return [t for t in previous.tracks if t.state is TrackState.SEEN]

    def _continue(
        self, tracker: str, human_id: str, detection: HumanCapsules, taken: set[int], margin_m: float, captured_ns: int
    ) -> Track | None:
        """The seen track of this tracker and id that the detection continues (it covers the track's last body within
        the reach since its last frame), or None."""
        candidates = [
            t
            for t in self.live
            if t.tracker == tracker
            and t.human_id == human_id
            and t.serial not in taken
            and t.last_seen_mono_ns < captured_ns
            and (t.state is TrackState.SEEN or self._by_id)
        ]
        for track in sorted(candidates, key=lambda t: -t.last_seen_mono_ns):
            reach_m = self.reach_speed_mps * (captured_ns - track.last_seen_mono_ns) / NS_PER_S + margin_m
            if covers(track.capsules, detection, reach_m):
                if track.state is TrackState.LOST:  # the replaced rule: the same id within reach continues it
                    self._lost.remove(track)
                    self._lost_cache = None
                    self._records = None
                return track
        return None

    def _new_track(
        self, tracker: str, human_id: str, frame: HumanCapsules, start: int, end: int, captured_ns: int
    ) -> Track:
        """A new track, and the person it joins: the one person whose bodies it is near, unless it touches the
        entry band (it may have come in); otherwise (none, several, or at the band) a new person."""
        self._serial += 1
        label = f"{tracker}/{human_id}"
        if any(t.label == label for t in self.live):
            label = f"{label}#{self._serial}"
        body = part(frame, start, end)
        near = self._near(body, tracker, captured_ns)
        near_persons = {t.person.serial: t.person for t in near}
        person: Person | None = None
        if len(near_persons) == 1 and (
            not touches_entry_band(body, self.tracking) or self._fragment_of(body, tracker, human_id, captured_ns, near)
        ):
            (candidate,) = near_persons.values()
            # a tracker reports each body once: beside its own detection of this frame, this is another body
            if not any(
                t.tracker == tracker and t.state is TrackState.SEEN and t.last_seen_mono_ns == captured_ns
                for t in candidate.tracks
            ) and (
                any(t.state is TrackState.LOST for t in near)  # the lost person seen again, within their reach
                or self._near(body, tracker, captured_ns, lambda t: t.person is candidate, JOIN_DT_MAX_S)
            ):
                person = candidate
        elif len(near_persons) > 1:
            names = ", ".join(sorted(p.label for p in near_persons.values()))
            for p in near_persons.values():
                if p.has_lost():
                    p.held_because = f"{label} appeared where it could be any of {names}"
        if person is None:
            person = self._new_person()
        track = Track(self._serial, label, tracker, human_id, frame, start, end, captured_ns, person)
        person.tracks.append(track)
        self.live.append(track)
        self._table.add(track, self._noise_m.get(tracker, 0.0))
        self._records = None
        return track

    def _fragment_of(
        self, body: HumanCapsules, tracker: str, human_id: str, captured_ns: int, near: Sequence[Track]
    ) -> bool:
        """Whether a new track is the body its tracker lost a moment ago: the same tracker and id, lost at most
        :data:`REAPPEAR_MAX_S` before, and inside that track's last body grown by what a person moves meanwhile (a
        frame missed, a part out of view). At the entry band too: a newcomer from outside cannot stand inside the
        body of the person seen there a moment ago."""
        margin_m = self._margin_m(tracker, tracker)
        for t in near:
            dt_s = (captured_ns - t.last_seen_mono_ns) / NS_PER_S
            if (
                t.tracker == tracker
                and t.human_id == human_id
                and t.state is TrackState.LOST
                and 0.0 < dt_s <= REAPPEAR_MAX_S
                and within(body, t.capsules, self.reach_speed_mps * dt_s + margin_m)
            ):
                return True
        return False

    def _new_person(self) -> Person:
        self._person_serial += 1
        return Person(self._person_serial)

    def _near(
        self,
        body: HumanCapsules,
        tracker: str,
        stamp_ns: int,
        keep: Callable[[Track], bool] | None = None,
        max_dt_s: float = math.inf,
    ) -> list[Track]:
        """Every live track (seen or lost; those ``keep`` accepts) whose last body ``body`` could be, or be part of:
        one lies inside the other grown by ``K_reach · min(|Δt|, max_dt_s)`` and both trackers' noise and margin. The
        cap makes a tight test for joining (a late stamp must not widen it)."""
        table = self._table
        if not table.tracks:
            return []
        lo, hi, r_max = _box(body)
        dt_s = np.minimum(np.abs(table.stamp_ns[: len(table.tracks)] - stamp_ns) / NS_PER_S, max_dt_s)
        grow = (
            self.reach_speed_mps * dt_s
            + self.tracking.association_margin_m
            + self._noise_m.get(tracker, 0.0)
            + table.noise_m[: len(table.tracks)]
        )
        maybe = table.may_nest(lo[None], hi[None], np.array([r_max]), grow[None])[0]
        out = []
        for k in np.flatnonzero(maybe):
            t = table.tracks[k]
            if (keep is None or keep(t)) and near(body, t.capsules, float(grow[k])):
                out.append(t)
        return sorted(out, key=lambda t: t.serial)

    def _others_near(self, observed: Sequence[Track]) -> list[list[Track]]:
        """Per observed track (seen), the seen tracks of other persons whose last body it could be, in the table's
        order: :meth:`_near`'s test (box, then body, grown by ``K_reach · |Δt|`` and both trackers' noise and
        margin). A matrix of boxes for the frame (most tracks are far from everybody else's), then every pair whose
        boxes may nest in one compiled call. Who belongs to which person is asked again where the answer is used:
        persons change as the frame is regrouped, bodies do not."""
        table = self._table
        n = len(table.tracks)
        out: list[list[Track]] = [[] for _ in observed]
        if n < 2 or not observed:
            return out
        rows = table.tracks
        persons = np.fromiter((t.person.serial for t in rows), np.int64, n)
        # the observed tracks are live, so rows of the table, whose box, capture time and noise are theirs (set when
        # they were seen in this frame)
        at = np.fromiter(map(table.row_of, observed), np.intp, len(observed))
        maybe = others_maybe_near(
            (table.lo_m[at], table.hi_m[at], table.radius_m[at], table.stamp_ns[at], table.noise_m[at], persons[at]),
            (
                table.lo_m[:n],
                table.hi_m[:n],
                table.radius_m[:n],
                table.stamp_ns[:n],
                table.noise_m[:n],
                persons,
                np.fromiter((t.state is TrackState.SEEN for t in rows), np.bool_, n),
            ),
            self.reach_speed_mps,
            self.tracking.association_margin_m,
        )
        maybe &= np.fromiter((t.state is TrackState.SEEN for t in observed), np.bool_, len(observed))[:, None]
        i, k = np.divmod(np.flatnonzero(maybe), n)  # np.nonzero of the matrix costs ~15× more
        if not len(i):
            return out
        mine = at[i]
        dt_s = np.abs(table.stamp_ns[k] - table.stamp_ns[mine]) / NS_PER_S
        margin_m = self.tracking.association_margin_m + table.noise_m[mine] + table.noise_m[k]
        grow = self.reach_speed_mps * dt_s + margin_m
        lo, hi, radius = table.lo_m, table.hi_m, table.radius_m
        boxes = _boxes_may_nest(lo[mine], hi[mine], radius[mine], lo[k], hi[k], radius[k], grow)
        i, k, mine, grow = i[boxes], k[boxes], mine[boxes], grow[boxes]
        involved, body = np.unique(np.concatenate((mine, k)), return_inverse=True)
        joined, starts, ends = _bodies_in_frames([rows[r] for r in involved.tolist()])
        is_near = slices_near(joined, starts, ends, body[: len(mine)], body[len(mine) :], grow)
        for a, b in zip(i[is_near].tolist(), k[is_near].tolist(), strict=True):
            out[a].append(rows[b])
        return out

    def _regroup(self, observed: Sequence[Track]) -> None:
        """Persons after a frame: a track near another person's seen track may have swapped bodies with it, so both
        leave their persons; unless neither person has a lost track and no tracker sees both (one body: they join)."""
        for track, near_bodies in zip(observed, self._others_near(observed), strict=True):
            if not near_bodies:
                continue
            own = track.person
            seen_others = [t for t in near_bodies if t.person is not own and t.state is TrackState.SEEN]
            if not seen_others:
                continue
            persons = {t.person.serial: t.person for t in seen_others}
            if len(persons) == 1:
                (other,) = persons.values()
                if (
                    self._joinable(own, other)
                    and self._near(
                        track.capsules,
                        track.tracker,
                        track.last_seen_mono_ns,
                        lambda t, other=other: t.person is other and t.state is TrackState.SEEN,  # type: ignore[misc]
                        JOIN_DT_MAX_S,
                    )
                    and not self._near(
                        track.capsules,
                        track.tracker,
                        track.last_seen_mono_ns,
                        lambda t, own=own, other=other: t.person is not own and t.person is not other,  # type: ignore[misc]
                    )
                ):
                    self._join(own, other)
                    continue
            self._detach(track)
            for t in seen_others:
                self._detach(t)

    @staticmethod
    def _joinable(a: Person, b: Person) -> bool:
        """Two persons may be one body when no tracker sees both (a tracker reports each body once)."""
        seen_a = {t.tracker for t in a.tracks if t.state is TrackState.SEEN}
        return not seen_a & {t.tracker for t in b.tracks if t.state is TrackState.SEEN}

    def _join(self, keep: Person, other: Person) -> None:
        for t in other.tracks:
            t.person = keep
        keep.tracks += other.tracks
        other.tracks = []
        self._records = None

    def _detach(self, track: Track) -> None:
        """Take a track out of its person into a person of its own (nothing to do when it is alone)."""
        if len(track.person.tracks) <= 1:
            return
        track.person.tracks.remove(track)
        person = self._new_person()
        person.tracks.append(track)
        track.person = person
        self._records = None

    def _lose(self, track: Track, now_mono_ns: int) -> list[TrackEvent]:
        track.state = TrackState.LOST
        self._lost.append(track)
        self._records = None
        face = leaving_face(track, self.tracking)
        if face is not None:
            return [self._release(track, now_mono_ns, ReleaseCause.LEFT, f"last seen leaving through face {face}")]
        return [
            TrackEvent(
                "track_lost", track.label, f"person {track.person.label} ({track.label}) lost: no longer reported"
            )
        ]

    def _margin_m(self, tracker_a: str, tracker_b: str) -> float:
        """How far two trackers' views of one person may differ beyond motion: the margin and their noise [m]."""
        return (
            self.tracking.association_margin_m + self._noise_m.get(tracker_a, 0.0) + self._noise_m.get(tracker_b, 0.0)
        )

    def _release_redetected(self) -> list[TrackEvent]:
        """Release every lost track that a seen track of its own person covers, captured after it was lost, when that
        seen track is near no lost track of another person (then it could be them)."""
        events: list[TrackEvent] = []
        for lost in list(self._lost):
            finders = list(self.live) if self._by_id else [t for t in lost.person.tracks if t.state is TrackState.SEEN]
            for seen in finders:
                if seen.state is not TrackState.SEEN or seen.last_seen_mono_ns <= lost.last_seen_mono_ns:
                    continue
                if self._by_id and touches_entry_band(seen.capsules, self.tracking):
                    continue
                reach_m = self.reach_speed_mps * (seen.last_seen_mono_ns - lost.last_seen_mono_ns) / NS_PER_S
                if not covers(lost.capsules, seen.capsules, reach_m + self._margin_m(lost.tracker, seen.tracker)):
                    continue
                if not self._by_id:
                    rivals = self._near(
                        seen.capsules,
                        seen.tracker,
                        seen.last_seen_mono_ns,
                        lambda t, mine=lost.person: t.state is TrackState.LOST and t.person is not mine,  # type: ignore[misc]
                    )
                    if rivals:
                        why = f"{seen.label} could also be {rivals[0].person.label} ({rivals[0].label}), lost nearby"
                        if lost.person.held_because != why:
                            lost.person.held_because = why
                            self._records = None
                        continue
                by = f"redetected by {seen.label} (person {seen.person.label})"
                events.append(self._release(lost, seen.last_seen_mono_ns, ReleaseCause.REDETECTED, by))
                break
        return events

    def _release_all_lost(self, now_mono_ns: int, cause: ReleaseCause, why: str) -> list[TrackEvent]:
        lost = list(self._lost)
        if lost:
            self._lost_cache = None
            self._records = None
        return [self._release(t, now_mono_ns, cause, why) for t in lost]

    def _release(self, track: Track, now_mono_ns: int, cause: ReleaseCause, why: str) -> TrackEvent:
        if track.state is TrackState.LOST:
            self._lost.remove(track)
        track.state = TrackState.RELEASED
        track.released_by = why
        track.released_mono_ns = now_mono_ns
        self.live.remove(track)
        self._table.remove(track)
        self.released.append(track)
        person = track.person
        if track in person.tracks:
            person.tracks.remove(track)
        if not person.has_lost():
            person.held_because = None
        self._records = None
        return TrackEvent(
            "track_released", track.label, f"person {person.label} ({track.label}) released: {why}", cause.value
        )

    # -- what the decisions use -----------------------------------------------------------------------------

    @property
    def overflow(self) -> bool:
        """More live tracks than :data:`MAX_LIVE_TRACKS` (a fault: δ = 0)."""
        return len(self.live) > MAX_LIVE_TRACKS

    def lost(self) -> list[Track]:
        """The lost tracks, in the order they were lost."""
        return list(self._lost)

    def persons(self) -> list[Person]:
        """Every person with a live track, in the order of their first track."""
        seen: dict[int, Person] = {}
        for t in self.live:
            seen.setdefault(t.person.serial, t.person)
        return list(seen.values())

    def reach_m(self, track: Track, now_mono_ns: int) -> float:
        """How far a lost person may be from where they were last seen at ``now`` [m]."""
        return self.reach_speed_mps * max(0, now_mono_ns - track.last_seen_mono_ns) / NS_PER_S

    def lost_capsules(self, now_mono_ns: int) -> HumanCapsules:
        """Every lost track's last capsules, radii grown by its reach at ``now``; human ids ``<label> (lost)``.

        The reach counts from the capture of the frame it was last seen in, so it overlaps the clearance's
        ``K · human_age_s`` by one frame age: conservative by that much.
        """
        lost = self._lost
        if not lost:
            return NO_HUMANS
        if self._lost_cache is None or self._lost_cache[0] != len(lost):
            merged = merge_humans(
                [t.capsules._replace(human_ids=(f"{t.label} (lost)",) * t.capsules.n_capsules) for t in lost]
            )
            self._lost_cache = (len(lost), merged)
        merged = self._lost_cache[1]
        grow = np.concatenate([np.full(t.capsules.n_capsules, self.reach_m(t, now_mono_ns)) for t in lost])
        return merged._replace(radius_m=merged.radius_m + grow)

    def records(self) -> tuple[TrackRecord, ...]:
        """Every live track and the recently released ones (newest last), for the status; the same tuple object
        while no track changed state or person (a seen track's newest frame does not count), so that the loop can
        hand it on every cycle for free."""
        if self._records is None:
            self._records = tuple(
                TrackRecord(
                    t.label,
                    t.tracker,
                    f"{t.tracker}/{t.human_id}" if t.state is TrackState.SEEN else f"{t.label} (lost)",
                    t.state,
                    None if t.state is TrackState.SEEN else t.last_seen_mono_ns,
                    t.n_capsules,
                    t.released_by,
                    t.person.label,
                    t.person.held_because if t.state is TrackState.LOST else None,
                )
                for t in (*self.live, *self.released)
            )
        return self._records


def _box(capsules: HumanCapsules) -> tuple[FloatArray, FloatArray, float]:
    """The box around the capsules' end points (lower, upper corner [m]) and their largest radius [m]."""
    ends = np.concatenate((capsules.h_a_world, capsules.h_b_world))
    return ends.min(axis=0), ends.max(axis=0), float(capsules.radius_m.max())


def frame_bodies_reference(
    capsules: HumanCapsules, starts: Sequence[int]
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per person of a frame (``starts``: :func:`human_starts`): the mean of their capsules' end points [m] and
    :func:`_box` of their capsules, as arrays. numpy, the reference of :func:`gateway.kernels.frame_bodies`."""
    if len(starts) < 2:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    at = np.asarray(starts[:-1])
    a, b = capsules.h_a_world, capsules.h_b_world
    return (
        np.add.reduceat(a + b, at, axis=0) / (2.0 * np.diff(starts))[:, None],
        np.minimum.reduceat(np.minimum(a, b), at, axis=0),
        np.maximum.reduceat(np.maximum(a, b), at, axis=0),
        np.maximum.reduceat(capsules.radius_m, at),
    )


def _boxes_may_nest(
    lo: FloatArray,
    hi: FloatArray,
    r_max: float | FloatArray,
    los: FloatArray,
    his: FloatArray,
    radii: FloatArray,
    grow: FloatArray,
) -> npt.NDArray[np.bool_]:
    """Per body of (``los``, ``his``, ``radii``): whether one body (box ``lo``–``hi``) may lie inside the other grown
    by ``grow`` [m], either way (or per pair, with a row of ``lo``, ``hi`` and ``r_max`` each). Necessary for
    :func:`gateway.bodies.near`: every end point of a body inside another grown by g lies within that one's largest
    radius plus g of its end points' box."""
    slack = (radii + grow)[:, None]
    inside_them = ((lo >= los - slack) & (hi <= his + slack)).all(axis=1)
    slack_own = (r_max + grow)[:, None]
    inside_it = ((los >= lo - slack_own) & (his <= hi + slack_own)).all(axis=1)
    return inside_them | inside_it  # type: ignore[return-value]


class _BoxTable:
    """The live tracks' boxes, radii, capture times and noise as arrays, one row per track (kept in step with
    ``TrackSet.live``), so that "who could be near this body" is one vector test per body, not a loop over tracks."""

    def __init__(self) -> None:
        self.tracks: list[Track] = []
        self._row: dict[int, int] = {}
        self.lo_m = np.zeros((64, 3))
        self.hi_m = np.zeros((64, 3))
        self.radius_m = np.zeros(64)
        self.stamp_ns = np.zeros(64)
        self.noise_m = np.zeros(64)

    def add(self, track: Track, noise_m: float) -> None:
        n = len(self.tracks)
        if n == len(self.radius_m):
            self.lo_m, self.hi_m = np.resize(self.lo_m, (2 * n, 3)), np.resize(self.hi_m, (2 * n, 3))
            self.radius_m, self.stamp_ns = np.resize(self.radius_m, 2 * n), np.resize(self.stamp_ns, 2 * n)
            self.noise_m = np.resize(self.noise_m, 2 * n)
        self.tracks.append(track)
        self._row[track.serial] = n
        self.noise_m[n] = noise_m
        self.set(track)

    def row_of(self, track: Track) -> int:
        """The track's row (it is live)."""
        return self._row[track.serial]

    def set(self, track: Track) -> None:
        """The track's box and capture time changed (it was seen)."""
        k = self._row[track.serial]
        self.lo_m[k], self.hi_m[k], self.radius_m[k] = track.box_lo_m, track.box_hi_m, track.radius_max_m
        self.stamp_ns[k] = track.last_seen_mono_ns

    def set_seen(self, tracks: Sequence[Track], lo_m: FloatArray, hi_m: FloatArray, radius_m: FloatArray) -> None:
        """:meth:`set` of tracks seen in one frame, whose boxes are these rows (one vector assignment per column
        instead of five per track: a crowd of 134 people ~100 µs a frame)."""
        if not tracks:
            return
        rows = np.fromiter((self._row[t.serial] for t in tracks), np.intp, len(tracks))
        self.lo_m[rows], self.hi_m[rows], self.radius_m[rows] = lo_m, hi_m, radius_m
        self.stamp_ns[rows] = tracks[0].last_seen_mono_ns

    def remove(self, track: Track) -> None:
        """The last row takes the removed one's place."""
        k = self._row.pop(track.serial)
        last = len(self.tracks) - 1
        moved = self.tracks.pop()
        if k != last:
            self.tracks[k] = moved
            self._row[moved.serial] = k
            for a in (self.lo_m, self.hi_m, self.radius_m, self.stamp_ns, self.noise_m):
                a[k] = a[last]

    def may_nest(
        self, lo_m: FloatArray, hi_m: FloatArray, radius_m: FloatArray, grow_m: FloatArray
    ) -> npt.NDArray[np.bool_]:
        """Per body given (rows of ``lo_m``, ``hi_m``, ``radius_m``) × per table row: whether one may lie inside the
        other grown by ``grow_m`` (bodies × rows) [m]; see :func:`_boxes_may_nest`."""
        n = len(self.tracks)
        return _may_nest_matrix(lo_m, hi_m, radius_m, self.lo_m[:n], self.hi_m[:n], self.radius_m[:n], grow_m)


def _may_nest_matrix(
    lo_m: FloatArray,
    hi_m: FloatArray,
    radius_m: FloatArray,
    rows_lo_m: FloatArray,
    rows_hi_m: FloatArray,
    rows_radius_m: FloatArray,
    grow_m: FloatArray,
) -> npt.NDArray[np.bool_]:
    """Per body (``lo_m``, ``hi_m``, ``radius_m``) × per row (``rows_*``): whether one may lie inside the other grown
    by ``grow_m`` (bodies × rows) [m]; see :func:`_boxes_may_nest`."""

    def gaps(axis: int) -> tuple[FloatArray, FloatArray]:
        below = lo_m[:, axis, None] - rows_lo_m[None, :, axis]
        above = rows_hi_m[None, :, axis] - hi_m[:, axis, None]
        return np.minimum(below, above), np.maximum(below, above)

    # per pair, the least and the most by which the others' box reaches past this one's: one (bodies × rows)
    # matrix per axis, no 3-D temporaries
    low_gap, high_gap = gaps(0)
    for axis in (1, 2):
        least, most = gaps(axis)
        np.minimum(low_gap, least, out=low_gap)
        np.maximum(high_gap, most, out=high_gap)
    inside_them = low_gap + rows_radius_m[None, :] + grow_m >= 0.0
    inside_it = radius_m[:, None] + grow_m - high_gap >= 0.0
    return inside_them | inside_it


def others_maybe_near_reference(
    bodies: BodyBoxes,
    rows: RowBoxes,
    reach_speed_mps: float,
    margin_m: float,
) -> npt.NDArray[np.bool_]:
    """numpy, the reference of :func:`gateway.kernels.others_maybe_near` (the arguments as there)."""
    lo, hi, r_max, stamps_ns, noise_m, person = bodies
    rows_lo, rows_hi, rows_r, rows_stamp_ns, rows_noise_m, rows_person, rows_seen = rows
    grow = (
        reach_speed_mps * np.abs(rows_stamp_ns[None, :] - stamps_ns[:, None]) / NS_PER_S
        + margin_m
        + noise_m[:, None]
        + rows_noise_m[None, :]
    )
    maybe = _may_nest_matrix(lo, hi, r_max, rows_lo, rows_hi, rows_r, grow)
    return maybe & rows_seen[None, :] & (person[:, None] != rows_person[None, :])  # type: ignore[no-any-return]


class _Previous(NamedTuple):
    """A tracker's previous frame and the tracks its people continued, in the frame's order."""

    capsules: HumanCapsules
    captured_ns: int
    tracks: tuple[Track, ...]


def _same_people(previous: _Previous, capsules: HumanCapsules) -> list[Track | None]:
    """Per human of ``capsules``: the track of the same position in the previous frame when both frames list the same
    people with the same parts in the same order (the steady state of a tracker) and that track is still seen; else
    None everywhere (decided one by one)."""
    n = len(previous.tracks)
    if previous.capsules.human_ids != capsules.human_ids or previous.capsules.capsule_names != capsules.capsule_names:
        return [None] * len(human_starts(capsules)[:-1]) if capsules.n_capsules else []
    return [t if t.state is TrackState.SEEN else None for t in previous.tracks[:n]]


def moved_within_reference(
    before: HumanCapsules, after: HumanCapsules, starts: Sequence[int], reach_m: float
) -> npt.NDArray[np.bool_]:
    """Per human (``starts``: index of each one's first capsule, and the end) of two frames listing the same capsules
    in the same order: whether every end point moved at most ``reach_m`` minus the growth of its radius [m]. numpy,
    the reference of :func:`gateway.kernels.moved_within`."""
    if after.n_capsules == 0:
        return np.zeros(0, dtype=bool)
    limit = reach_m - np.maximum(after.radius_m - before.radius_m, 0.0)
    da = after.h_a_world - before.h_a_world
    db = after.h_b_world - before.h_b_world
    da2 = da[:, 0] * da[:, 0] + da[:, 1] * da[:, 1] + da[:, 2] * da[:, 2]
    db2 = db[:, 0] * db[:, 0] + db[:, 1] * db[:, 1] + db[:, 2] * db[:, 2]
    ok = (da2 <= limit * limit) & (db2 <= limit * limit)
    ok &= limit >= 0.0
    return np.logical_and.reduceat(ok, list(starts[:-1]))


CHECK_FRAMES = 32
CHECK_SEED = 20260415
CENTRE_TOLERANCE_M = 1e-12
"""The compiled centres may differ from numpy's in the order of the sum (numpy's reduction does not promise one):
by a few ulp; boxes, radii and every yes/no must match exactly."""


def _random_frame(rng: np.random.Generator, n_people: int) -> tuple[HumanCapsules, npt.NDArray[np.int64]]:
    sizes = rng.integers(1, 16, n_people)
    frame = random_capsules(rng, tuple(f"h{p}" for p, size in enumerate(sizes) for _ in range(size)), 3.0)
    return frame, np.array(human_starts(frame), dtype=np.int64)


@functools.cache  # once per process: the compiled code does not change in it
def check_frame_kernels(seed: int = CHECK_SEED) -> None:
    """Hold the compiled frame path (:func:`gateway.kernels.frame_bodies`, :func:`gateway.kernels.moved_within`,
    :func:`gateway.kernels.others_maybe_near`) to its numpy references on seeded random frames: bit for bit, the
    centres within :data:`CENTRE_TOLERANCE_M` (and compile it, or load it from numba's cache, before the first frame).

    Raises:
        ConfigError: the two disagree on a frame.
    """
    rng = np.random.default_rng(seed)
    for k in range(CHECK_FRAMES):
        after, starts = _random_frame(rng, int(rng.integers(1, 6)))
        n = after.n_capsules
        moved = rng.uniform(0.0, 0.3) * (rng.random((n, 1)) < 0.9)
        before = after._replace(
            h_a_world=after.h_a_world + rng.uniform(-1.0, 1.0, (n, 3)) * moved,
            h_b_world=after.h_b_world + rng.uniform(-1.0, 1.0, (n, 3)) * moved,
            radius_m=after.radius_m + rng.uniform(-0.05, 0.05, n),
        )
        reach_m = float(rng.uniform(0.0, 0.5))
        compiled_bodies = frame_bodies(after, starts)
        reference_bodies = frame_bodies_reference(after, list(starts))
        centres_off_m = float(np.max(np.abs(compiled_bodies[0] - reference_bodies[0]), initial=0.0))
        rows_n = int(rng.integers(1, 12))
        rows_lo = rng.uniform(-3.0, 3.0, (rows_n, 3))
        rows: RowBoxes = (
            rows_lo,
            rows_lo + rng.uniform(0.0, 2.0, (rows_n, 3)),
            rng.uniform(0.0, 0.3, rows_n),
            rng.uniform(0.0, 1e9, rows_n),
            rng.uniform(0.0, 0.05, rows_n),
            rng.integers(0, 4, rows_n).astype(np.int64),
            rng.random(rows_n) < 0.7,
        )
        people = len(starts) - 1
        bodies: BodyBoxes = (
            reference_bodies[1],
            reference_bodies[2],
            reference_bodies[3],
            rng.uniform(0.0, 1e9, people),
            rng.uniform(0.0, 0.05, people),
            rng.integers(0, 4, people).astype(np.int64),
        )
        speed, margin = float(rng.uniform(1.0, 2.0)), float(rng.uniform(0.0, 0.3))
        got: list[npt.NDArray[np.generic]] = [
            *compiled_bodies[1:],
            moved_within(before, after, starts, reach_m),
            others_maybe_near(bodies, rows, speed, margin),
        ]
        expected: list[npt.NDArray[np.generic]] = [
            *reference_bodies[1:],
            moved_within_reference(before, after, list(starts), reach_m),
            others_maybe_near_reference(bodies, rows, speed, margin),
        ]
        if not centres_off_m <= CENTRE_TOLERANCE_M or not all(
            np.array_equal(g, e) for g, e in zip(got, expected, strict=True)
        ):
            raise ConfigError(f"the compiled frame path differs from its numpy reference on seeded frame {k}")
