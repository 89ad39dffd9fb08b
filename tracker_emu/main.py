"""The tracker emulator process: plays a scenario's humans as one or several sensors over Zenoh.

clock → TrackerEmulator.step(now, robot links) → publish the frames due → TruthSampler.step(now) → publish the truth
→ sleep until the next capture, publication or truth sample

Sensors report only people inside the cell's covered volume (``[tracking]``). When a sensor has occlusion, the
process follows the robots' true joint positions (``hrc/<cell>/truth/robot/*/state``, published by the controller
emulators) and passes their link capsules to each capture; until a robot's first state arrives, it hides nothing.

The ground truth (the scenario's capsules before noise, drops and latency) goes out at ``--truth-rate-hz``
on ``hrc/<cell>/truth/humans`` as a humans message of tracker ``truth``, stamped and published at once.
It is for the auditor; the gateway subscribes only to ``hrc/<cell>/tracker/*/humans``.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple

import zenoh

from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError, TrackerConfig
from hrc_contract.messages import to_payload
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments, run_program
from hrc_runtime.config import load_cell_config
from hrc_runtime.realtime import freeze_startup_heap
from hrc_runtime.sd_notify import LoopNotifier
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args, session_config
from tracker_emu.emulator import TrackerEmulator, TruthSampler
from tracker_emu.robot_links import RobotPoses
from tracker_emu.ros2_zed import (
    ZedPublishers,
    ros2_endpoints,
    ros2_session_options,
    with_body_fitting,
    zed_sources,
)
from tracker_emu.scenario import Scenario, load_scenario, scenario_path
from tracker_emu.sensor import covered_volume

log = logging.getLogger("hrc-tracker-emu")

PROG = "hrc-tracker-emu"
PROGRESS_EVERY_S = 5.0
DEFAULT_TRUTH_RATE_HZ = 100.0
MAX_TRUTH_RATE_HZ = 1000.0
COMPONENT = "tracker-emu"
"""Name of the liveliness token: ``hrc/<cell>/alive/tracker-emu``."""


def select_trackers(config: CellConfig, names: Sequence[str] | None) -> dict[str, TrackerConfig]:
    """The trackers to play: the named ones, or all of the cell's when ``names`` is empty or None.

    Raises:
        ConfigError: a name is not a tracker of the cell; the message lists them.
    """
    if not names:
        return dict(config.trackers)
    unknown = [n for n in names if n not in config.trackers]
    if unknown:
        raise ConfigError(
            f"unknown tracker {', '.join(map(repr, unknown))}; trackers of cell {config.cell!r}: "
            f"{', '.join(config.trackers)}"
        )
    return {n: config.trackers[n] for n in dict.fromkeys(names)}


def select_scenario(config: CellConfig, name: str | None) -> tuple[str, Scenario]:
    """The scenario to play: the named one or the cell's default, loaded from the cell's scenarios folder.

    Raises:
        ConfigError: unknown name (the message lists the available scenarios) or invalid file.
    """
    name = name or config.default_scenario
    return name, load_scenario(scenario_path(config.scenarios_dir, name))


def _progress(emulator: TrackerEmulator, now_s: float) -> str:
    counters = "; ".join(
        f"{name}: {c.published} published, {c.dropped} dropped"
        + (f", {c.skipped} skipped" if c.skipped else "")
        + (f", {c.id_swaps} id swaps" if c.id_swaps else "")
        for name, c in emulator.counters.items()
    )
    return (
        f"scenario t = {emulator.scenario_time_s(now_s):.1f} s, humans: {', '.join(emulator.present_ids) or 'none'}; "
        + counters
    )


class _Publishers(NamedTuple):
    """The tracker emulator's publishers: one per tracker it plays, and the ground truth's."""

    humans: dict[str, zenoh.Publisher]
    truth: zenoh.Publisher
    zed: ZedPublishers | None = None
    """``--publish zed``: the trackers' frames as ZED ObjectsStamped over rmw_zenoh instead of ``humans``."""


def _declare_publishers(session: zenoh.Session, cell: str, trackers: Iterable[str]) -> _Publishers:
    def declare(key: str) -> zenoh.Publisher:
        return session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON, express=True)

    return _Publishers(
        {name: declare(keys.tracker_humans(cell, name)) for name in trackers}, declare(keys.truth_humans(cell))
    )


def robot_poses(config: CellConfig) -> RobotPoses:
    """The cell's robot models, loaded, waiting for their true joint positions.

    Raises:
        ConfigError: a robot's URDF or links do not load.
    """
    return RobotPoses(config.cell, {name: load_robot_model(name, robot) for name, robot in config.robots.items()})


def _truth_state_callback(robots: RobotPoses) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        robots.on_truth_state(str(sample.key_expr), sample.payload.to_bytes())

    return on_sample


def _log_start(cell: str, scenario_name: str, scenario: Scenario, trackers: dict[str, TrackerConfig]) -> None:
    log.info(
        "cell %r: playing scenario %r (%.1f s%s: %s) as tracker(s) %s",
        cell,
        scenario_name,
        scenario.duration_s,
        ", loop" if scenario.loop else "",
        scenario.description,
        ", ".join(
            f"{n} ({t.rate_hz:g} Hz, latency {t.latency_s:g} s"
            + (f", occlusion from {t.position_m}" if t.occlusion else "")
            + ")"
            for n, t in trackers.items()
        ),
    )


def _publish_due(
    emulator: TrackerEmulator,
    truth: TruthSampler | None,
    publishers: _Publishers,
    robots: RobotPoses | None,
    now_s: float,
    now_ns: int,
) -> bool:
    """Publish the frames due at ``now_s`` and the truth sample, if one is due; whether a frame went out."""
    published = False
    # Forward kinematics only when a sensor with occlusion captures.
    robot_links = robots.capsules() if robots is not None and emulator.capture_due(now_s) else None
    for name, message in emulator.step(now_s, now_ns, robot_links):
        if publishers.zed is not None:
            publishers.zed.publish(name, message, emulator.present_ids)
        else:
            publishers.humans[name].put(emulator.payload(name, message))
        published = True
    truth_message = truth.step(now_s, now_ns) if truth is not None else None
    if truth_message is not None:
        publishers.truth.put(to_payload(truth_message))
    return published


class _Course:
    """What the log says of the scenario's course: each restart of a loop, the end of a single run, and
    progress every :data:`PROGRESS_EVERY_S`."""

    def __init__(self, scenario_name: str, scenario: Scenario, start_s: float) -> None:
        self.scenario_name = scenario_name
        self.scenario = scenario
        self.next_progress_s = start_s + PROGRESS_EVERY_S
        self.loop_index = 0
        self.ended = False

    def update(self, emulator: TrackerEmulator, now_s: float) -> None:
        name, scenario = self.scenario_name, self.scenario
        if scenario.loop and emulator.loop_index(now_s) != self.loop_index:
            self.loop_index = emulator.loop_index(now_s)
            log.info("scenario %r restarts (run %d); %s", name, self.loop_index + 1, _progress(emulator, now_s))
        elif not scenario.loop and not self.ended and emulator.elapsed_s(now_s) >= scenario.duration_s:
            self.ended = True
            log.info("scenario %r ended; publishing empty frames until stopped", name)
        if now_s >= self.next_progress_s:
            self.next_progress_s = now_s + PROGRESS_EVERY_S
            log.info(_progress(emulator, now_s))


def _play(
    emulator: TrackerEmulator,
    truth: TruthSampler | None,
    publishers: _Publishers,
    robots: RobotPoses | None,
    course: _Course,
    stop: threading.Event,
) -> None:
    """Publish what is due, then sleep until the next capture, publication, truth sample, progress line or
    watchdog ping; until ``stop`` is set."""
    service = LoopNotifier.from_environment()  # READY=1 after the first frame, WATCHDOG=1, STATUS=
    published = False
    freeze_startup_heap()
    while not stop.is_set():
        now_s = time.monotonic()
        published = _publish_due(emulator, truth, publishers, robots, now_s, time.time_ns()) or published
        service.cycle_done(now_s, lambda: _progress(emulator, time.monotonic()), ready=published)
        course.update(emulator, now_s)
        next_s = min(emulator.next_event_s(), course.next_progress_s, now_s + service.ping_every_s)
        if truth is not None:
            next_s = min(next_s, truth.next_event_s())
        stop.wait(max(0.0, next_s - time.monotonic()))
    service.stopping()


def main(
    config: CellConfig,
    scenario_name: str,
    scenario: Scenario,
    trackers: dict[str, TrackerConfig],
    seed: int,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    truth_rate_hz: float = DEFAULT_TRUTH_RATE_HZ,
    *,
    zenoh_options: SessionOptions,
    robots: RobotPoses | None = None,
    ros2_options: SessionOptions | None = None,
) -> int:
    """Play ``scenario`` for ``trackers`` in real time until ``stop`` is set. Returns the exit code.

    ``truth_rate_hz``: rate of the ground truth on ``hrc/<cell>/truth/humans`` [Hz]; 0 publishes none.
    ``robots``: the robot models the sensors with occlusion see (default: loaded here when a tracker occludes).
    ``ros2_options``: given, the trackers speak ZED over rmw_zenoh on a session of their own (``--publish zed``,
    :mod:`tracker_emu.ros2_zed`), to ``[ros2]``'s endpoints; the truth stays on the cell's session.

    Raises:
        ConfigError: a robot model does not load (only when ``robots`` is not given).
    """
    cell = config.cell
    if robots is None and any(t.occlusion for t in trackers.values()):
        robots = robot_poses(config)
    zed_session = None
    if ros2_options is not None:
        zed_session = zenoh.open(session_config(connect=ros2_endpoints(config), options=ros2_options))
    with zenoh.open(session_config(listen, connect, zenoh_options)) as session, zed_session or session:
        publishers = _declare_publishers(session, cell, [] if zed_session else trackers)
        if zed_session is not None:
            noise = {name: t.noise_std_m for name, t in trackers.items()}
            zed = ZedPublishers(zed_session, config, zed_sources(config, trackers), noise)
            publishers = publishers._replace(zed=zed)
        subscriber = (
            None
            if robots is None
            else session.declare_subscriber(f"hrc/{cell}/truth/robot/*/state", _truth_state_callback(robots))
        )
        token = session.liveliness().declare_token(keys.alive(cell, COMPONENT))
        emulator = TrackerEmulator(
            scenario, trackers, seed, start_s=time.monotonic(), coverage=covered_volume(config.tracking)
        )
        truth = TruthSampler(scenario, truth_rate_hz, emulator.start_s) if truth_rate_hz > 0.0 else None
        _log_start(cell, scenario_name, scenario, trackers)
        _play(emulator, truth, publishers, robots, _Course(scenario_name, scenario, emulator.start_s), stop)
        if publishers.zed is not None:
            publishers.zed.close()
        del token, publishers, subscriber  # undeclared when the session closes
    log.info("stopped; %s", _progress(emulator, time.monotonic()))
    return 0


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=PROG, description="Tracker emulator: scripted humans as capsules over Zenoh")
    add_config_argument(parser)
    parser.add_argument("--scenario", default=None, help="scenario name (default: the cell's default_scenario)")
    parser.add_argument(
        "--tracker",
        action="append",
        default=[],
        metavar="NAME",
        help="tracker of the cell to play (repeatable; default: all of them)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise and drops (default 0)")
    parser.add_argument(
        "--truth-rate-hz",
        type=float,
        default=DEFAULT_TRUTH_RATE_HZ,
        metavar="HZ",
        help="rate of the ground truth on hrc/<cell>/truth/humans, for the auditor "
        f"(default {DEFAULT_TRUTH_RATE_HZ:g}; 0 = none)",
    )
    parser.add_argument(
        "--publish",
        choices=("capsules", "zed"),
        default="capsules",
        help="what the trackers publish: hrc.humans/1 capsules on the cell's Zenoh (default), or ZED "
        "zed_msgs/ObjectsStamped over rmw_zenoh to [ros2]'s endpoints (trackers need a zed_objects ros2 input)",
    )
    parser.add_argument(
        "--zed-body-fitting",
        choices=("on", "off"),
        default=None,
        help="with --publish zed: the cameras' body_tracking.enable_body_fitting (ZED wrapper): on = BODY_34, hidden "
        "keypoints fitted; off = BODY_38, hidden keypoints NaN (default: each tracker's enable_body_fitting in the "
        "cell file, false unless set: the wrapper's default; docs/ros2.md)",
    )
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    if args.zed_body_fitting is not None and args.publish != "zed":
        parser.error("--zed-body-fitting applies to --publish zed only")
    if not 0.0 <= args.truth_rate_hz <= MAX_TRUTH_RATE_HZ:  # also rejects NaN
        print(
            f"{PROG}: invalid configuration: --truth-rate-hz {args.truth_rate_hz}; allowed: 0 (none) to "
            f"{MAX_TRUTH_RATE_HZ:g} Hz",
            file=sys.stderr,
        )
        sys.exit(2)
    connect = args.zenoh_connect or ([] if args.zenoh_listen else [DEFAULT_ENDPOINT])

    def body(stop: StopEvent) -> int:
        config = load_cell_config(args.config)
        scenario_name, scenario = select_scenario(config, args.scenario)
        trackers = select_trackers(config, args.tracker)
        robots = robot_poses(config) if any(t.occlusion for t in trackers.values()) else None
        zenoh_options = options_from_args(args, COMPONENT, config)  # mutual TLS + access control by default
        ros2_options = None
        if args.publish == "zed":
            zed_sources(config, trackers)  # refuses trackers without a ZED input before anything starts
            if args.zed_body_fitting is not None:
                trackers = with_body_fitting(trackers, args.zed_body_fitting == "on")
            ros2_options = ros2_session_options(args, ros2_endpoints(config))
        return main(
            config,
            scenario_name,
            scenario,
            trackers,
            args.seed,
            args.zenoh_listen,
            connect,
            stop,
            truth_rate_hz=args.truth_rate_hz,
            zenoh_options=zenoh_options,
            robots=robots,
            ros2_options=ros2_options,
        )

    run_program(PROG, args.log_level, body, log=log)


if __name__ == "__main__":
    cli()
