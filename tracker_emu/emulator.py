"""The tracker emulator as a step function: which frames are captured and published when. No I/O, no clock.

Every sensor captures at its own ``rate_hz`` from the start of the scenario; a capture takes the true
humans at that scenario time through the sensor model and queues the measured frame for publication
``latency_s`` later, stamped with the wall-clock time of the capture. The caller passes the clocks in, and the
robots' link capsules when a sensor with occlusion captures (:attr:`TrackerEmulator.occludes`):

    emulator = TrackerEmulator(scenario, trackers, seed, start_s=time.monotonic(), coverage=box)
    while running:
        now_s = time.monotonic()
        links = robot_poses.capsules() if emulator.occludes and emulator.capture_due(now_s) else None
        for tracker, message in emulator.step(now_s, time.time_ns(), links):
            publish(tracker, message)
        sleep until emulator.next_event_s()
"""

from __future__ import annotations

import heapq
import math
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from hrc_contract.config import Box, TrackerConfig
from hrc_contract.humans import packed_payload
from hrc_contract.messages import Humans, to_payload
from tracker_emu.occlusion import NO_BLOCKERS, Blockers, fixture_blockers, join_blockers
from tracker_emu.scenario import Scenario, TrackedHuman, humans_at, scenario_time
from tracker_emu.sensor import humans_message, measure, merge_close, names_by_kind, rename, renew_ids, swap_ids


@dataclass
class TrackerCounters:
    """What one emulated sensor did so far.

    Attributes:
        captured: frames captured (published, queued or dropped).
        published: frames handed out for publication (= the last ``seq``).
        dropped: frames lost by the sensor model, never published.
        skipped: capture instants missed because the caller came late (the loop overran).
        id_swaps: times two reported people exchanged their ids.
    """

    captured: int = 0
    published: int = 0
    dropped: int = 0
    skipped: int = 0
    id_swaps: int = 0


@dataclass
class _Sensor:
    name: str
    config: TrackerConfig
    rng: np.random.Generator
    period_s: float
    next_capture_s: float
    counters: TrackerCounters = field(default_factory=TrackerCounters)
    names: dict[str, str] = field(default_factory=dict)
    """The id this sensor gives each true id (after id swaps); a true id not in it keeps its own."""


@dataclass(frozen=True, order=True)
class _Pending:
    due_s: float
    order: int
    tracker: str = field(compare=False)
    stamp_ns: int = field(compare=False)
    humans: list[TrackedHuman] = field(compare=False)


def tracker_rng(seed: int, tracker: str) -> np.random.Generator:
    """The random generator of one sensor: fixed by the seed and the sensor's name, whatever else runs."""
    return np.random.default_rng([seed, zlib.crc32(tracker.encode())])


class TrackerEmulator:
    """Plays a scenario for one or several sensors.

    Args:
        scenario: the scripted humans.
        trackers: the sensors to play, by name.
        seed: seed of the sensors' noise, drops, misses and id swaps.
        start_s: monotonic time at which the scenario starts (scenario time 0) [s].
        coverage: the volume the cell's trackers cover (``[tracking]``): nobody outside it is reported; None =
            everywhere.
    """

    def __init__(
        self,
        scenario: Scenario,
        trackers: Mapping[str, TrackerConfig],
        seed: int,
        start_s: float,
        *,
        coverage: Box | None = None,
    ) -> None:
        if not trackers:
            raise ValueError("at least one tracker is required")
        self.scenario = scenario
        self.start_s = start_s
        self.coverage = coverage
        self._fixtures = fixture_blockers(scenario.fixtures)
        self._sensors = {
            name: _Sensor(name, config, tracker_rng(seed, name), 1.0 / config.rate_hz, start_s)
            for name, config in trackers.items()
        }
        self._pending: list[_Pending] = []
        self._order = 0
        self.present_ids: tuple[str, ...] = ()
        """Ids of the humans present at the latest capture."""

    @property
    def counters(self) -> dict[str, TrackerCounters]:
        return {name: sensor.counters for name, sensor in self._sensors.items()}

    def elapsed_s(self, now_s: float) -> float:
        """Time since the scenario started [s]."""
        return now_s - self.start_s

    def scenario_time_s(self, now_s: float) -> float:
        """Scenario time at monotonic time ``now_s`` (wrapped when the scenario loops) [s]."""
        return scenario_time(self.scenario, self.elapsed_s(now_s))

    def loop_index(self, now_s: float) -> int:
        """How many times the scenario has restarted by ``now_s`` (0 during the first run)."""
        return math.floor(max(0.0, self.elapsed_s(now_s)) / self.scenario.duration_s)

    def payload(self, tracker: str, message: Humans) -> bytes:
        """``message`` written as ``tracker`` writes its frames (``trackers.<name>.wire``: JSON or packed)."""
        packed = self._sensors[tracker].config.wire == "packed"
        return packed_payload(message) if packed else to_payload(message)

    @property
    def occludes(self) -> bool:
        """Whether a sensor sees only what is in its line of sight (and so needs the robots' link capsules)."""
        return any(sensor.config.occlusion for sensor in self._sensors.values())

    def capture_due(self, now_s: float) -> bool:
        """Whether a sensor captures at ``now_s`` (monotonic time [s]): the robots' links are needed only then."""
        return any(sensor.next_capture_s <= now_s for sensor in self._sensors.values())

    def next_event_s(self) -> float:
        """Monotonic time of the next capture or publication [s]."""
        next_capture_s = min(sensor.next_capture_s for sensor in self._sensors.values())
        return min(next_capture_s, self._pending[0].due_s) if self._pending else next_capture_s

    def step(self, now_s: float, now_ns: int, robot_links: Blockers | None = None) -> list[tuple[str, Humans]]:
        """Capture the frames that are due, then hand out the frames whose latency has passed.

        Args:
            now_s: monotonic time [s].
            now_ns: wall-clock time at ``now_s``, nanoseconds since the Unix epoch (the capture stamp).
            robot_links: the robots' link capsules at ``now_s``, world frame [m], for the sensors with occlusion;
                None = no robot in sight (only people hide anything).

        Returns:
            ``(tracker, message)`` pairs to publish now, in capture order.
        """
        humans_true: list[TrackedHuman] | None = None
        blockers = NO_BLOCKERS
        for sensor in self._sensors.values():
            if sensor.next_capture_s > now_s:
                continue
            if humans_true is None:
                humans_true = humans_at(self.scenario, self.elapsed_s(now_s))
                self.present_ids = tuple(h.id for h in humans_true)
                blockers = join_blockers([NO_BLOCKERS if robot_links is None else robot_links, self._fixtures])
            self._capture(sensor, humans_true, now_s, now_ns, blockers)
        out = []
        while self._pending and self._pending[0].due_s <= now_s:
            frame = heapq.heappop(self._pending)
            counters = self._sensors[frame.tracker].counters
            counters.published += 1
            out.append((frame.tracker, humans_message(frame.tracker, counters.published, frame.stamp_ns, frame.humans)))
        return out

    def _capture(
        self, sensor: _Sensor, humans_true: list[TrackedHuman], now_s: float, now_ns: int, blockers: Blockers
    ) -> None:
        sensor.counters.captured += 1
        config = sensor.config
        blind = self.elapsed_s(now_s) < config.blind_until_s
        measured = measure([] if blind else humans_true, sensor.rng, config, coverage=self.coverage, blockers=blockers)
        if measured is None:
            sensor.counters.dropped += 1
        else:
            names = swap_ids(measured, sensor.names, sensor.rng, config.id_swap_probability)
            sensor.counters.id_swaps += names != sensor.names
            names = renew_ids(measured, names, sensor.rng, config.id_renew_probability, sensor.counters.captured)
            sensor.names = names
            reported = merge_close(rename(measured, names), config.merge_within_m)
            if config.part_names_by_kind:
                reported = names_by_kind(reported)
            self._order += 1
            stamp_ns = now_ns - round(config.stamp_late_s * 1e9)
            heapq.heappush(
                self._pending, _Pending(now_s + config.latency_s, self._order, sensor.name, stamp_ns, reported)
            )
        # Next capture on the sensor's own grid; instants already past are skipped, not caught up in a burst.
        sensor.next_capture_s += sensor.period_s
        if sensor.next_capture_s <= now_s:
            missed = math.floor((now_s - sensor.next_capture_s) / sensor.period_s) + 1
            sensor.counters.skipped += missed
            sensor.next_capture_s += missed * sensor.period_s


TRUTH_TRACKER = "truth"
"""``tracker`` field of the ground-truth messages (``hrc/<cell>/truth/humans``)."""


class TruthSampler:
    """The true humans at a fixed rate, for the auditor: no noise, no drops, no latency.

    Samples the scenario on its own grid from the scenario start (``start_s``); each sample is stamped
    with the wall-clock time of that instant and handed out at once. Instants missed by a late caller are
    skipped (counted), not caught up in a burst.

    Args:
        scenario: the scripted humans.
        rate_hz: sampling rate [Hz] (> 0).
        start_s: monotonic time of scenario time 0 (the :class:`TrackerEmulator`'s ``start_s``) [s].
    """

    def __init__(self, scenario: Scenario, rate_hz: float, start_s: float) -> None:
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)):
            raise ValueError(f"truth rate {rate_hz} Hz; allowed: a finite rate > 0")
        self.scenario = scenario
        self.start_s = start_s
        self.period_s = 1.0 / rate_hz
        self._next_index = 0  # the grid is start_s + k · period_s: no drift from adding periods up
        self.published = 0
        self.skipped = 0

    def next_event_s(self) -> float:
        """Monotonic time of the next truth sample [s]."""
        return self.start_s + self._next_index * self.period_s

    def step(self, now_s: float, now_ns: int) -> Humans | None:
        """The truth message of this instant if a sample is due, else None.

        Args:
            now_s: monotonic time [s].
            now_ns: wall-clock time at ``now_s``, nanoseconds since the Unix epoch (the stamp).
        """
        if now_s < self.next_event_s():
            return None
        # The next instant after now on the grid; the ones in between are skipped, not caught up.
        following = max(self._next_index + 1, math.floor((now_s - self.start_s) / self.period_s) + 1)
        self.skipped += following - self._next_index - 1
        self._next_index = following
        self.published += 1
        humans = humans_at(self.scenario, now_s - self.start_s)
        return humans_message(TRUTH_TRACKER, self.published, now_ns, humans)
