"""People as tracks: a person the trackers stop reporting is *lost*, never gone (docs/contract.md "Tracks").

Separation monitoring rests on one assumption: people move at most at K. A person no longer reported (hidden by
the robot or by another person, a missed detection, a tracker glitch) is somewhere within ``K · (time since last
seen)`` of where they were last seen, so the gateway keeps them:

    tracker frame ──update──▶ tracks: seen ──(not in a newer frame of its tracker)──▶ lost ──▶ released
                                         ◀──(same id, within reach)── lost            (redetected | left | reset)

- **seen**: in its tracker's newest frame; its capsules are that frame's.
- **lost**: its last capsules, each radius grown by ``K_reach · (now − last seen)`` (K_reach: ISO 13855's close
  range speed where configured, else K). It enters every robot's decision like a seen person.
- **released**, only by
  (a) *redetected*: a person of a new frame (any tracker, captured after the track was last seen) who has every part
      the track had, each within its reach, and who can be them: one person accounts for one track, so someone who
      continues their own track (seen all along) releases nobody, unless that track is a *twin* (another tracker's
      view of the same person when it was lost); someone who appeared inside the covered volume after the track was
      lost (nobody enters there: a *claim*) may release one lost track; a newcomer at the boundary releases none.
      The same id outside the reach is another person and the lost one stays;
  (b) *left*: when lost, it was last seen within ``tracking.exit_band_m`` of a side face of the covered volume
      (inside an exit zone where the cell declares them), moving out through that face;
  (c) *reset*: an operator, after checking the area, released it with an authenticated command.
  Never by a timeout.

A detection outside a track's reach (a 3 m jump in one frame, an id swap) is not motion: the old track is lost where
it was and the detection is a new track. Pure: no I/O, no clock; every time is passed in (monotonic [ns]).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_contract.config import CellConfig, TrackingConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules, merge_humans

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
NOISE_SIGMAS = 3.0
"""A tracker's position noise, ``noise_std_m``, counts this many times in the association margin."""


class TrackState(StrEnum):
    SEEN = "seen"
    LOST = "lost"
    RELEASED = "released"


class ReleaseCause(StrEnum):
    REDETECTED = "redetected"
    LEFT = "left"
    RESET = "reset"
    FORGOTTEN = "forgotten_unsafe_test_only"


class Detection(NamedTuple):
    """One human of one tracker frame.

    Attributes:
        tracker: the tracker's name.
        human_id: the id the tracker gave (without the tracker prefix).
        capsules: its capsules (human ids ``<tracker>/<id>``).
        captured_mono_ns: when the frame was captured, on the gateway's monotonic clock [ns].
    """

    tracker: str
    human_id: str
    capsules: HumanCapsules
    captured_mono_ns: int
    frame: HumanCapsules
    start: int
    end: int


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
    """

    label: str
    tracker: str
    human: str
    state: TrackState
    last_seen_mono_ns: int | None
    capsules: int
    released_by: str | None = None


@dataclass(eq=False)
class Track:
    """One person as one tracker followed them; their capsules are a slice of the frame they were last seen in."""

    serial: int
    label: str
    tracker: str
    human_id: str
    frame: HumanCapsules
    start: int
    end: int
    last_seen_mono_ns: int
    state: TrackState = TrackState.SEEN
    centres: deque[tuple[int, FloatArray]] = field(default_factory=lambda: deque(maxlen=64))
    released_by: str | None = None
    released_mono_ns: int = 0
    last_centre: FloatArray | None = None
    claim: bool = False
    """It appeared inside the covered volume (nobody enters there): it may be someone lost before it appeared, and may
    release such lost tracks it covers, of one person only: once it released one, only the other fragments of that
    one (the same tracker and id, e.g. the tracks a person left behind while parts of them were hidden one after the
    other). A track that appears at the boundary is a newcomer."""
    claimed: tuple[str, str] | None = None
    """The (tracker, id) of the lost person its claim was spent on."""
    first_seen_mono_ns: int = 0
    twins: frozenset[int] = frozenset()
    """Serials of other trackers' tracks that covered it when it was lost: the same person, still seen elsewhere."""
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

    def observe(self, frame: HumanCapsules, start: int, end: int, captured_ns: int, centre_m: FloatArray) -> None:
        """Seen in ``frame[start:end]``, captured at ``captured_ns``, its centre at ``centre_m`` [m]."""
        self.frame, self.start, self.end, self._capsules = frame, start, end, None
        self.last_seen_mono_ns = captured_ns
        self.state = TrackState.SEEN
        self.last_centre = centre_m
        centres = self.centres
        if not centres or captured_ns - centres[-1][0] >= CENTRE_SAMPLE_NS:
            centres.append((captured_ns, centre_m))
            if captured_ns - centres[0][0] > VELOCITY_WINDOW_NS:
                centres.popleft()


def centre(capsules: HumanCapsules) -> FloatArray:
    """Mean of all capsule end points [m]."""
    return np.concatenate((capsules.h_a_world, capsules.h_b_world)).mean(axis=0)  # type: ignore[no-any-return]


def human_starts(capsules: HumanCapsules) -> list[int]:
    """Index of each human's first capsule (a frame lists each human's capsules together), and the end."""
    ids = capsules.human_ids
    n = len(ids)
    return [0, *(i for i in range(1, n) if ids[i] != ids[i - 1]), n] if n else [0]


def part(capsules: HumanCapsules, start: int, end: int) -> HumanCapsules:
    """Capsules ``start:end`` of a frame (views of its arrays)."""
    c = capsules
    return HumanCapsules(
        c.h_a_world[start:end],
        c.h_b_world[start:end],
        c.radius_m[start:end],
        c.human_ids[start:end],
        c.capsule_names[start:end],
    )


def split_frame(tracker: str, capsules: HumanCapsules, captured_mono_ns: int) -> list[Detection]:
    """A tracker frame's capsules as one detection per human (in the frame's order)."""
    starts = human_starts(capsules)
    prefix = len(tracker) + 1
    return [
        Detection(
            tracker,
            capsules.human_ids[start][prefix:],
            part(capsules, start, end),
            captured_mono_ns,
            capsules,
            start,
            end,
        )
        for start, end in itertools.pairwise(starts)
    ]


def reach_speed_mps(config: CellConfig) -> float:
    """How fast a lost person's possible positions grow: ISO 13855's close-range speed where configured, else K."""
    safety = config.safety
    return safety.human_speed_close_mps if safety.close_speed_below_m > 0.0 else safety.human_speed_mps


def in_entry_band(centre_m: FloatArray, tracking: TrackingConfig) -> bool:
    """Whether a centre lies where people enter the covered volume: within ``exit_band_m`` of a side face (inside an
    exit zone where the cell declares them), or outside the volume."""
    if tracking.exit_zones and not any(
        all(lo <= x <= hi for x, lo, hi in zip(centre_m, zone.min_m, zone.max_m, strict=True))
        for zone in tracking.exit_zones
    ):
        return False
    low, high = tracking.coverage_min_m, tracking.coverage_max_m
    return any(
        centre_m[axis] - low[axis] <= tracking.exit_band_m or high[axis] - centre_m[axis] <= tracking.exit_band_m
        for axis in (0, 1)
    )


def leaving_face(track: Track, tracking: TrackingConfig) -> str | None:
    """The side face of the covered volume through which a track was last seen leaving, or None.

    Its last centre lies within ``exit_band_m`` of the face (and in an exit zone where the cell declares them) and
    its centre moved out through that face at ``exit_speed_min_mps`` or more over its last observations; a centre
    already outside the covered volume counts as having left through the nearest face.
    """
    if not track.centres or track.last_centre is None:
        return None
    (t0_ns, c0), (t1_ns, c1) = track.centres[0], (track.last_seen_mono_ns, track.last_centre)
    span_ns = t1_ns - t0_ns
    if span_ns < VELOCITY_MIN_SPAN_NS:
        return None
    velocity = (c1 - c0) / (span_ns / NS_PER_S)
    if tracking.exit_zones and not any(
        all(lo <= x <= hi for x, lo, hi in zip(c1, zone.min_m, zone.max_m, strict=True)) for zone in tracking.exit_zones
    ):
        return None
    low, high = tracking.coverage_min_m, tracking.coverage_max_m
    for axis, name in ((0, "x"), (1, "y")):
        if c1[axis] - low[axis] <= tracking.exit_band_m and -velocity[axis] >= tracking.exit_speed_min_mps:
            return f"-{name}"
        if high[axis] - c1[axis] <= tracking.exit_band_m and velocity[axis] >= tracking.exit_speed_min_mps:
            return f"+{name}"
    return None


class TrackSet:
    """Every person the cell's trackers reported, seen or lost, and the ones recently released.

    Args:
        config: the cell (``tracking``, K, the trackers' noise).
    """

    def __init__(self, config: CellConfig) -> None:
        self.tracking = config.tracking
        self.reach_speed_mps = reach_speed_mps(config)
        self._noise_m = {name: NOISE_SIGMAS * t.noise_std_m for name, t in config.trackers.items()}
        self._forget = config.tracking.unsafe_forget_lost_for_tests
        self.live: list[Track] = []
        self._lost: list[Track] = []
        self._previous: dict[str, _Previous] = {}
        self.released: deque[Track] = deque(maxlen=RELEASED_KEPT)
        self._serial = 0
        self._frames: dict[str, object] = {}
        self._lost_cache: tuple[int, HumanCapsules] | None = None
        self._records: tuple[TrackRecord, ...] | None = None

    # -- updates ------------------------------------------------------------------------------------------

    def update(
        self, frames: Mapping[str, tuple[object, HumanCapsules, int] | None], now_mono_ns: int
    ) -> list[TrackEvent]:
        """Take every tracker frame that is new since the last call.

        Args:
            frames: per tracker, ``(identity, capsules, captured_mono_ns)`` of its newest valid frame (the identity
                tells a new frame from the one already taken), or None without one.
            now_mono_ns: the decision time [ns].

        Returns:
            The tracks' changes (lost, released), in order.
        """
        events: list[TrackEvent] = []
        new: list[_People] = []
        for tracker, frame in frames.items():
            if frame is None or self._frames.get(tracker) is frame[0]:
                continue
            self._frames[tracker] = frame[0]
            taken, people = self._take_frame(tracker, frame[1], frame[2])
            events += taken
            new.append(people)
        if events or self._lost:
            events += self._release_redetected(new)
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

    def _take_frame(self, tracker: str, capsules: HumanCapsules, captured_ns: int) -> tuple[list[TrackEvent], _People]:
        """Match one tracker's frame to its tracks by id within reach; the rest of its seen tracks are lost.

        The common case, the same people with the same parts as in this tracker's previous frame, is decided for the
        whole frame at once (:func:`moved_within`); any other detection by the general rule (:meth:`_match`).

        Returns:
            The changes, and the frame's people (for the releases: any of them, continuing a track or not, may be a
            lost person seen again).
        """
        margin_m = self._margin_m(tracker, tracker)
        previous = self._previous.get(tracker)
        starts = human_starts(capsules)
        prefix = len(tracker) + 1
        observed: set[int] = set()
        continued = [None] * (len(starts) - 1) if previous is None else _same_people(previous, capsules)
        centres = (
            np.add.reduceat(capsules.h_a_world + capsules.h_b_world, starts[:-1], axis=0)
            / (2.0 * np.diff(starts))[:, None]
            if len(starts) > 1
            else np.zeros((0, 3))
        )
        if previous is not None and any(t is not None for t in continued):
            dt_s = (captured_ns - previous.captured_ns) / NS_PER_S
            ok = moved_within(previous.capsules, capsules, starts, self.reach_speed_mps * dt_s + margin_m)
            continued = [t if t is not None and ok[k] else None for k, t in enumerate(continued)]
        order: list[Track] = []
        for k, (start, end) in enumerate(itertools.pairwise(starts)):
            track = continued[k]
            if track is None:
                detection = Detection(
                    tracker,
                    capsules.human_ids[start][prefix:],
                    part(capsules, start, end),
                    captured_ns,
                    capsules,
                    start,
                    end,
                )
                track = self._match(detection, observed, margin_m, captured_ns) or self._new_track(detection)
                if track.state is TrackState.LOST:  # the same person, seen again by their tracker within reach
                    self._lost.remove(track)
                    self._lost_cache = None
                self._records = None
            track.observe(capsules, start, end, captured_ns, centres[k])
            observed.add(track.serial)
            order.append(track)
        events: list[TrackEvent] = []
        for track in self._seen_of(tracker):
            if track.serial not in observed:
                events += self._lose(track, captured_ns)
        self._previous[tracker] = _Previous(capsules, captured_ns, tuple(order))
        return events, _People(tracker, capsules, starts, centres, captured_ns, tuple(order))

    def _seen_of(self, tracker: str) -> list[Track]:
        previous = self._previous.get(tracker)
        if previous is None:
            return []
        return [t for t in previous.tracks if t.state is TrackState.SEEN]

    def _match(self, detection: Detection, observed: set[int], margin_m: float, captured_ns: int) -> Track | None:
        """The track a detection continues (its tracker, its id, within reach, every part there), or None."""
        candidates = [
            t
            for t in self.live
            if t.tracker == detection.tracker
            and t.human_id == detection.human_id
            and t.serial not in observed
            and t.last_seen_mono_ns < captured_ns
        ]
        # the newest track of that id first: after a glitch the lost one stays where it was
        for track in sorted(candidates, key=lambda t: -t.last_seen_mono_ns):
            reach_m = self.reach_speed_mps * (captured_ns - track.last_seen_mono_ns) / NS_PER_S + margin_m
            if _continues(track.capsules, detection.capsules, reach_m):
                return track
        return None

    def _new_track(self, detection: Detection) -> Track:
        self._serial += 1
        label = f"{detection.tracker}/{detection.human_id}"
        if any(t.label == label for t in self.live):
            label = f"{label}#{self._serial}"
        track = Track(
            self._serial,
            label,
            detection.tracker,
            detection.human_id,
            detection.frame,
            detection.start,
            detection.end,
            0,
        )
        track.claim = not in_entry_band(centre(detection.capsules), self.tracking)
        track.first_seen_mono_ns = detection.captured_mono_ns
        self.live.append(track)
        return track

    def _lose(self, track: Track, now_mono_ns: int) -> list[TrackEvent]:
        track.state = TrackState.LOST
        self._lost.append(track)
        self._records = None
        track.twins = frozenset(
            other.serial
            for other in self.live
            if other.tracker != track.tracker
            and other.state is TrackState.SEEN
            and _continues(
                track.capsules,
                other.capsules,
                self.reach_speed_mps * abs(other.last_seen_mono_ns - track.last_seen_mono_ns) / NS_PER_S
                + self._margin_m(track.tracker, other.tracker),
            )
        )
        face = leaving_face(track, self.tracking)
        if face is not None:
            return [self._release(track, now_mono_ns, ReleaseCause.LEFT, f"last seen leaving through face {face}")]
        return [TrackEvent("track_lost", track.label, f"person {track.label} lost: no longer reported")]

    def _margin_m(self, tracker_a: str, tracker_b: str) -> float:
        """How far two trackers' views of one person may differ beyond motion: the margin and their noise [m]."""
        return (
            self.tracking.association_margin_m + self._noise_m.get(tracker_a, 0.0) + self._noise_m.get(tracker_b, 0.0)
        )

    def _release_redetected(self, frames: Sequence[_People]) -> list[TrackEvent]:
        """Release every lost track that a person of a new frame accounts for.

        One person accounts for one track: a person who continues their own track (someone else, seen all along)
        releases nobody, unless that track is a twin of the lost one (another tracker's view of the same person).
        A person who appeared inside the covered volume (a claim: nobody enters there) may release one lost track.
        Either way the person must have every part the lost track had, each within its reach (a partial view
        never releases a whole person).
        """
        events: list[TrackEvent] = []
        for track in list(self._lost):
            track_centre = centre(track.capsules)
            released = None
            for people in frames:
                dt_ns = people.captured_ns - track.last_seen_mono_ns
                if dt_ns <= 0 or not len(people.centres):
                    continue
                reach_m = self.reach_speed_mps * dt_ns / NS_PER_S + self._margin_m(track.tracker, people.tracker)
                near = np.flatnonzero(np.linalg.norm(people.centres - track_centre, axis=1) <= reach_m + 2.5)
                for k in near:  # a person is at most ~2.5 m across: one whose centre is farther cannot cover it
                    finder = people.tracks[int(k)]
                    twin = finder.serial in track.twins
                    person = (track.tracker, track.human_id)
                    claim = (
                        finder.claim
                        and finder.claimed in (None, person)
                        and finder.first_seen_mono_ns > track.last_seen_mono_ns
                    )
                    if (twin or claim) and _continues(track.capsules, people.person(int(k)), reach_m):
                        if not twin:
                            finder.claimed = person
                        by = f"redetected by {finder.label}" + (" (the same person, seen by another tracker)" * twin)
                        released = self._release(track, people.captured_ns, ReleaseCause.REDETECTED, by)
                        break
                if released is not None:
                    events.append(released)
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
        self.released.append(track)
        return TrackEvent("track_released", track.label, f"person {track.label} released: {why}", cause.value)

    # -- what the decisions use -----------------------------------------------------------------------------

    @property
    def overflow(self) -> bool:
        """More live tracks than :data:`MAX_LIVE_TRACKS` (a fault: δ = 0)."""
        return len(self.live) > MAX_LIVE_TRACKS

    def lost(self) -> list[Track]:
        """The lost tracks, in the order they were lost."""
        return list(self._lost)

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
        while no track changed state (a seen track's newest frame does not count), so that the loop can hand it on
        every cycle for free."""
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
                )
                for t in (*self.live, *self.released)
            )
        return self._records


def _continues(track: HumanCapsules, detection: HumanCapsules, reach_m: float) -> bool:
    """Whether a detection with the track's id continues it: every capsule the track has is in the detection under
    the same name, and each end point moved at most ``reach_m`` (a missing part or a jump starts a new track and
    leaves this one lost, where it was)."""
    index = {name: i for i, name in enumerate(detection.capsule_names)}
    rows = [index.get(name, -1) for name in track.capsule_names]
    if min(rows, default=0) < 0:
        return False
    rows_arr = np.asarray(rows, dtype=np.intp)
    moved_a = np.linalg.norm(detection.h_a_world[rows_arr] - track.h_a_world, axis=1)
    moved_b = np.linalg.norm(detection.h_b_world[rows_arr] - track.h_b_world, axis=1)
    grown = detection.radius_m[rows_arr] - track.radius_m
    limit = reach_m - np.maximum(grown, 0.0)
    return bool(((moved_a <= limit) & (moved_b <= limit)).all()) and math.isfinite(reach_m)


class _People(NamedTuple):
    """The people of one new tracker frame: the frame, each one's first capsule (and the end), their centres [m]."""

    tracker: str
    capsules: HumanCapsules
    starts: list[int]
    centres: FloatArray
    captured_ns: int
    tracks: tuple[Track, ...]
    """The track each person continues (or started), in the frame's order."""

    def person(self, k: int) -> HumanCapsules:
        """The capsules of the frame's k-th person (human ids ``<tracker>/<id>``)."""
        return part(self.capsules, self.starts[k], self.starts[k + 1])


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


def moved_within(
    before: HumanCapsules, after: HumanCapsules, starts: Sequence[int], reach_m: float
) -> npt.NDArray[np.bool_]:
    """Per human (``starts``: index of each one's first capsule, and the end) of two frames listing the same capsules
    in the same order: whether every end point moved at most ``reach_m`` minus the growth of its radius [m]."""
    if after.n_capsules == 0:
        return np.zeros(0, dtype=bool)
    limit = reach_m - np.maximum(after.radius_m - before.radius_m, 0.0)
    da = after.h_a_world - before.h_a_world
    db = after.h_b_world - before.h_b_world
    ok = (np.einsum("ij,ij->i", da, da) <= limit * limit) & (np.einsum("ij,ij->i", db, db) <= limit * limit)
    ok &= limit >= 0.0
    return np.logical_and.reduceat(ok, list(starts[:-1]))
