"""Prometheus metrics of the gateway (``GET /metrics``), computed in the HTTP child from the status documents.

Nothing here runs in the safety loop: the child observes each status document as it arrives (histograms of the
loop's timing, faults raised), each event of the log as it arrives (people released, by cause) and reads the newest
document when scraped (gauges and counters the gateway already counts, the people tracked). Names follow Prometheus'
conventions: prefix ``hrc_``, base units (seconds, metres), ``_total`` for counters, ratios in 0–1.

A status document carries every tick period since the previous document (``loop.tick_periods_s``), the longest loop
iteration and the lateness of the last tick. The period histogram observes each tick's period; its buckets lie
around the configured period, so that its quantiles are tails, not interpolations of means.

Releases are counted from the ``track_released`` events, not from the status: the status keeps only the 32 most
recent released tracks, a released label may come back (the same person lost and released again), and the child may
skip status documents; it receives every event once.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from gateway.stalls import CAUSES as STALL_CAUSES
from hrc_contract.status_models import Event, GatewayStatus

MS_BUCKETS_S = (0.0005, 0.001, 0.002, 0.003, 0.004, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.05, 0.1)
"""Histogram buckets for the loop's compute time and lateness: 0.5 ms to 100 ms [s]."""
PERIOD_BUCKET_RATIOS = (0.5, 0.9, 0.95, 0.98, 0.99, 1.01, 1.02, 1.05, 1.1, 1.25, 1.5, 2.0, 3.0)
"""Upper edges of the period histogram's buckets, as multiples of the configured tick period."""
ZONES = ("autonomous", "guarded_distance", "reduced_speed", "safety_exception")
TRACK_STATES = ("seen", "lost")
"""The states ``hrc_tracks`` counts (the released ones are a count of events: ``hrc_tracks_released_total``)."""
RELEASE_CAUSES = ("redetected", "left", "reset")
"""Causes of ``track_released`` (docs/contract.md "Tracks"), exported at 0 before the first."""
NS_PER_S = 1e9


class _StatusCollector(Collector):
    """Gauges and counters read from the newest status document at scrape time."""

    def __init__(self, metrics: GatewayMetrics) -> None:
        self._metrics = metrics

    def collect(self) -> Iterator[Metric]:
        status = self._metrics.latest
        if status is None:
            return
        yield from _robot_metrics(status)
        yield from _input_metrics(status)
        yield from _track_metrics(status)
        loop = status.loop
        yield CounterMetricFamily("hrc_loop_cycles", "Decisions taken (ticks and event cycles).", value=loop.cycles)
        yield CounterMetricFamily("hrc_loop_missed_cycles", "Ticks skipped after an overrun.", value=loop.missed_cycles)
        yield from _stall_metrics(status)
        if loop.rate_hz > 0.0:
            yield GaugeMetricFamily(
                "hrc_loop_nominal_period_seconds",
                "Configured tick period of the safety loop.",
                value=1.0 / loop.rate_hz,
            )


def _stall_metrics(status: GatewayStatus) -> Iterator[Metric]:
    """Stalls and the ticks they skipped, by cause (every cause of :mod:`gateway.stalls` at 0 before the first)."""
    stalls = CounterMetricFamily("hrc_loop_stalls", "Ticks later than a period, by cause.", labels=["cause"])
    missed = CounterMetricFamily(
        "hrc_loop_missed_cycles_by_cause", "Ticks skipped, by the cause of the stall.", labels=["cause"]
    )
    loop = status.loop
    for cause in dict.fromkeys((*STALL_CAUSES, *loop.stalls, *loop.missed_by_cause)):
        stalls.add_metric([cause], loop.stalls.get(cause, 0))
        missed.add_metric([cause], loop.missed_by_cause.get(cause, 0))
    yield stalls
    yield missed


def _robot_metrics(status: GatewayStatus) -> Iterator[Metric]:
    delta = GaugeMetricFamily("hrc_robot_delta_ratio", "Override δ commanded (0–1).", labels=["robot"])
    applied = GaugeMetricFamily("hrc_robot_delta_applied_ratio", "Override δ the controller applies.", labels=["robot"])
    zone = GaugeMetricFamily("hrc_robot_zone", "1 for the robot's zone, 0 for the others.", labels=["robot", "zone"])
    distance = GaugeMetricFamily("hrc_robot_min_distance_meters", "Smallest robot-human distance.", labels=["robot"])
    clearance = GaugeMetricFamily("hrc_robot_clearance_meters", "The clearance Δ.", labels=["robot"])
    t_delay = GaugeMetricFamily("hrc_robot_t_delay_seconds", "The whole delay t_delay.", labels=["robot"])
    part = GaugeMetricFamily("hrc_robot_delay_part_seconds", "The parts of t_delay.", labels=["robot", "part"])
    faults = GaugeMetricFamily("hrc_robot_faults_active", "Active faults by code.", labels=["robot", "code"])
    for name, robot in status.robots.items():
        delta.add_metric([name], robot.delta)
        if robot.delta_applied is not None:
            applied.add_metric([name], robot.delta_applied)
        for z in ZONES:
            zone.add_metric([name, z], 1.0 if robot.zone == z else 0.0)
        if robot.min_distance_m is not None:
            distance.add_metric([name], robot.min_distance_m)
        clearance.add_metric([name], robot.clearance_m)
        t_delay.add_metric([name], robot.t_delay_s)
        for key, value in robot.delay_budget_s.model_dump().items():
            part.add_metric([name, key.removesuffix("_s")], value)
        for fault in robot.faults:
            faults.add_metric([name, fault.code], 1.0)
    yield from (delta, applied, zone, distance, clearance, t_delay, part, faults)


def _input_metrics(status: GatewayStatus) -> Iterator[Metric]:
    received = CounterMetricFamily("hrc_inputs_received", "Valid input messages stored.", labels=["topic"])
    rejected = CounterMetricFamily("hrc_inputs_rejected", "Input messages rejected.", labels=["topic", "reason"])
    for topic, count in status.inputs.received.items():
        received.add_metric([topic], count)
    for topic, reasons in status.inputs.rejected.items():
        for reason, count in reasons.items():
            rejected.add_metric([topic, reason], count)
    yield received
    yield rejected


def _track_metrics(status: GatewayStatus) -> Iterator[Metric]:
    tracks = GaugeMetricFamily(
        "hrc_tracks", "People tracked, by state: seen, or lost (kept, growing at K).", labels=["state"]
    )
    for state in TRACK_STATES:
        tracks.add_metric([state], sum(1 for t in status.tracks if t.state == state))
    yield tracks
    yield GaugeMetricFamily(
        "hrc_track_lost_age_max_seconds",
        "Time since the longest-lost person was last seen; 0 with nobody lost.",
        value=max((t.last_seen_age_s for t in status.tracks if t.state == "lost"), default=0.0),
    )


def period_buckets(period_s: float) -> tuple[float, ...]:
    """Bucket edges around the tick period ``period_s`` [s] (:data:`PERIOD_BUCKET_RATIOS` of it, to 1 ns)."""
    return tuple(round(ratio * period_s, 9) for ratio in PERIOD_BUCKET_RATIOS)


def raised_faults(previous: GatewayStatus | None, status: GatewayStatus) -> list[tuple[str, str]]:
    """``(robot, code)`` of each fault active in ``status`` and not in ``previous`` (all of them in the first)."""
    raised = []
    for name, robot in status.robots.items():
        before = None if previous is None else previous.robots.get(name)
        codes = set() if before is None else {f.code for f in before.faults}
        raised += [(name, f.code) for f in robot.faults if f.code not in codes]
    return raised


class GatewayMetrics:
    """The metrics registry; :meth:`observe` each status document as it arrives (thread-safe).

    Args:
        period_s: the loop's configured tick period (``1 / gateway.rate_hz``), the centre of the period
            histogram's buckets [s].
    """

    def __init__(self, period_s: float) -> None:
        self.registry = CollectorRegistry()
        self.latest: GatewayStatus | None = None
        self._lock = threading.Lock()
        self._previous: GatewayStatus | None = None
        self.period = Histogram(
            "hrc_loop_period_seconds",
            "Each tick's interval from the previous tick.",
            buckets=period_buckets(period_s),
            registry=self.registry,
        )
        self.compute = Histogram(
            "hrc_loop_compute_max_seconds",
            "Longest decision between two status documents.",
            buckets=MS_BUCKETS_S,
            registry=self.registry,
        )
        self.lateness = Histogram(
            "hrc_loop_lateness_seconds", "Lateness of the last tick.", buckets=MS_BUCKETS_S, registry=self.registry
        )
        self.faults_raised = Counter(
            "hrc_faults_raised", "Faults raised, by robot and code.", ["robot", "code"], registry=self.registry
        )
        self.tracks_released = Counter(
            "hrc_tracks_released",
            "People released (no longer lost), by cause: redetected, left or reset.",
            ["cause"],
            registry=self.registry,
        )
        for cause in RELEASE_CAUSES:
            self.tracks_released.labels(cause)
        self._last_event_seq = 0
        self.registry.register(_StatusCollector(self))

    def observe(self, status: GatewayStatus) -> None:
        """One status document arrived."""
        with self._lock:
            previous, self._previous, self.latest = self._previous, status, status
            self.compute.observe(status.loop.compute_max_s)
            self.lateness.observe(status.loop.last_lateness_s)
            for name, code in raised_faults(previous, status):
                self.faults_raised.labels(name, code).inc()
            for period_s in status.loop.tick_periods_s:
                self.period.observe(period_s)

    def observe_event(self, event: Event) -> None:
        """One event of the log arrived; an event of a seq already observed is not counted again."""
        with self._lock:
            if event.seq <= self._last_event_seq:
                return
            self._last_event_seq = event.seq
            if event.kind == "track_released":
                self.tracks_released.labels(event.cause or "unknown").inc()

    def exposition(self) -> bytes:
        """The Prometheus text format."""
        with self._lock:
            return generate_latest(self.registry)
