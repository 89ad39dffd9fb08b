"""``hrc-record``: every topic of a cell to an MCAP file, with 3D capsules for Foxglove and Lichtblick.

    hrc-record --output cell.mcap [--config PATH] [--zenoh-connect ENDPOINT] [--events-url URL]
    hrc-record --format ros2 [--distro humble|jazzy|kilted] --output cell_bag     # a ROS 2 bag instead

It connects as a Zenoh client (``--zenoh-mode client`` by default) to the gateway, a peer that routes every
topic of the cell to its clients; ``--zenoh-mode peer`` to meet the programs directly instead.

A Zenoh member of the cell with the ``recorder`` certificate (it may subscribe, never put; see
:mod:`hrc_runtime.pki`). Every message of the contract's topics is written as it arrived (payload bytes
unchanged, ``log_time`` = its arrival on this host's wall clock), on a channel named after its key
(``/hrc/<cell>/robot/<robot>/state`` ...) with the JSON Schema of its model:

- joint states and ground-truth joint states (``hrc.joint_state``), overrides (``hrc.override``), tracker
  frames and ground-truth humans (``hrc.humans``), the gateway status (``hrc.gateway_status``);
- the gateway's event log (``hrc.event``, ``/hrc/<cell>/gateway/events``), polled from its REST API
  (``GET /api/v1/events?since=…``, the gateway publishes no events on Zenoh): ``log_time`` is when the poll
  answered, like every other message's arrival (the first poll brings the events since the gateway started,
  which can be long before the recorder); when each was logged is its ``stamp_ns``;
- ``foxglove.SceneUpdate`` on ``/scene/humans/<tracker>`` (each frame's people) and ``/scene/robots`` (the
  links of each status, coloured by zone; an open robot's plan around people as a line, ``plan/<robot>``), with
  Foxglove's own schema (:func:`hrc_tools.record.scene.foxglove_schema`);
- payloads that are not a valid message of their key on ``/hrc/<cell>/rejected`` (``hrc.rejected``), so a
  hostile input is kept as evidence without breaking a reader that trusts the schemas.

Ctrl-C (or SIGTERM) closes the file (footer and summary written): it opens in any MCAP reader.

``--format ros2`` writes a ROS 2 bag instead (a folder with its MCAP file and ``metadata.yaml``, CDR messages of
the ``--distro``'s definitions, default ``[ros2] distro``): the same messages, validated the same way, as the ROS 2
types of the gateway's ROS 2 face (:mod:`hrc_tools.record.ros2_cell`, :mod:`hrc_tools.record.ros2_mcap`).
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal, Protocol, get_args

import zenoh
from pydantic import BaseModel, TypeAdapter, ValidationError

from hrc_contract.config import CellConfig, ConfigError, Ros2Distro
from hrc_contract.messages import Humans
from hrc_contract.status_models import Event, EventsResponse, GatewayStatus
from hrc_runtime.access_control import RECORDER
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import configure_logging
from hrc_runtime.mcap_sink import McapSink, RecordingError, identity
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args, session_config
from hrc_tools.record import scene
from hrc_tools.record.ros2_cell import Ros2Cell, Ros2CellRecorder
from hrc_tools.record.ros2_mcap import Ros2BagSink
from hrc_tools.record.topics import (
    EVENT,
    REJECTED,
    SCENE,
    RejectedPayload,
    receive,
    subscriptions,
)

log = logging.getLogger("hrc-record")

PROG = "hrc-record"
EVENTS_POLL_S = 0.5
"""How often the gateway's event log is polled [s]."""
PROGRESS_EVERY_S = 10.0


def _scene_update(message: BaseModel, received_ns: int) -> scene.SceneUpdate | None:
    if isinstance(message, Humans):
        return scene.humans_scene(message, received_ns)
    if isinstance(message, GatewayStatus):
        return scene.robots_scene(message, received_ns)
    return None


def _encode_model(message: BaseModel) -> bytes:
    return message.model_dump_json().encode()


class CellRecorder:
    """Writes what the subscribers receive to the sink (callbacks on Zenoh threads; the sink never blocks)."""

    def __init__(self, sink: McapSink, cell: str) -> None:
        self.sink = sink
        self.cell = cell
        self.unknown_keys = 0

    def on_sample(self, key: str, payload: bytes, received_ns: int) -> None:
        """Record one payload received on ``key``: on its channel, or as rejected; plus its scene update."""
        received = receive(self.cell, key, payload)
        if received is None:
            self.unknown_keys += 1
            return
        if isinstance(received, RejectedPayload):
            self.sink.offer(f"/hrc/{self.cell}/rejected", REJECTED, received_ns, _encode_model, received)
            return
        topic, message = received
        self.sink.offer(f"/{key}", topic.channel, received_ns, identity, payload)
        update = _scene_update(message, received_ns)
        if update is not None and topic.scene_topic is not None:
            self.sink.offer(topic.scene_topic, SCENE, received_ns, _encode_model, update)

    def on_events(self, events: Sequence[Event], received_ns: int) -> None:
        """Record the events of one poll of the gateway's log, answered at ``received_ns`` (their ``log_time``)."""
        for event in events:
            self.sink.offer(f"/hrc/{self.cell}/gateway/events", EVENT, received_ns, _encode_model, event)


_EVENTS = TypeAdapter(EventsResponse)


def fetch_events(url: str, since: int, timeout_s: float = 2.0) -> EventsResponse:
    """``GET {url}/api/v1/events?since=…`` of the gateway.

    Raises:
        OSError: the gateway does not answer (``urllib.error.URLError`` is one).
        ValidationError: the answer is not the contract's.
    """
    with urllib.request.urlopen(f"{url}/api/v1/events?since={since}", timeout=timeout_s) as response:
        return _EVENTS.validate_json(response.read())


class Recorder(Protocol):
    """What the subscribers and the event poller feed: :class:`CellRecorder` (JSON) or
    :class:`hrc_tools.record.ros2_cell.Ros2CellRecorder` (ROS 2 bag)."""

    def on_sample(self, key: str, payload: bytes, received_ns: int) -> None: ...

    def on_events(self, events: Sequence[Event], received_ns: int) -> None: ...


def _callback(recorder: Recorder) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        received_ns = time.time_ns()
        try:
            recorder.on_sample(str(sample.key_expr), sample.payload.to_bytes(), received_ns)
        except Exception:  # a callback must never die
            log.exception("error while recording a message on %s", sample.key_expr)

    return on_sample


class _EventPoller:
    """The gateway's event log since the last poll; says once when the gateway stops or starts answering."""

    def __init__(self, url: str | None) -> None:
        self.url = url
        self.since = 0
        self.answering: bool | None = None

    def poll(self) -> list[Event]:
        if self.url is None:
            return []
        try:
            response = fetch_events(self.url, self.since)
        except (OSError, ValidationError) as exc:
            if self.answering is not False:
                log.warning("gateway events at %s: no answer (%s); polling on", self.url, exc)
            self.answering = False
            return []
        if self.answering is not True:
            log.info("gateway events at %s: recording", self.url)
        self.answering = True
        self.since = response.last_seq
        return list(response.events)


JOIN_WITHIN_S = 30.0
"""A client recorder started with the cell (``hrc-cell --record``) may come up before the gateway listens: it
tries to join for this long [s] before it gives up."""


def _join(config: zenoh.Config, stop: threading.Event) -> zenoh.Session:
    """Open the session, retrying every 0.5 s for :data:`JOIN_WITHIN_S` (or until ``stop``).

    Raises:
        zenoh.ZError: the last attempt's error, once the time is up.
    """
    deadline_s = time.monotonic() + JOIN_WITHIN_S
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError:
            if time.monotonic() >= deadline_s or stop.wait(0.5):
                raise


def run_recorder(
    config: CellConfig,
    output: Path,
    listen: Sequence[str],
    connect: Sequence[str],
    stop: threading.Event,
    events_url: str | None,
    *,
    zenoh_options: SessionOptions,
    output_format: Literal["json", "ros2"] = "json",
    distro: Ros2Distro | None = None,
) -> int:
    """Record until ``stop`` is set. Returns the number of messages written.

    Args:
        output_format: ``json``, an MCAP file of the contract's JSON; ``ros2``, a ROS 2 bag (folder) in ``distro``
            (default ``[ros2] distro``).

    Raises:
        RecordingError: the output cannot be created (or, for a ROS 2 bag, exists).
    """
    metadata = {"hrc.cell_recording": {"cell": config.cell, "config_sha256": config.sha256()}}
    session_cm = _join(session_config(listen, connect, zenoh_options), stop)
    sink: McapSink | Ros2BagSink
    recorder: Recorder
    if output_format == "ros2":
        cell = Ros2Cell.of(config, distro or config.ros2.distro)
        bag = Ros2BagSink(output, cell.distro, custom_data=metadata["hrc.cell_recording"])
        sink, recorder = bag, Ros2CellRecorder(bag, cell, time.time_ns())
    else:
        mcap = McapSink(output, metadata=metadata)
        sink, recorder = mcap, CellRecorder(mcap, config.cell)
    with sink, session_cm as session:
        subscribers = [session.declare_subscriber(k, _callback(recorder)) for k in subscriptions(config.cell)]
        log.info("recording cell %r to %s (%s)", config.cell, output, ", ".join(subscriptions(config.cell)))
        poller = _EventPoller(events_url)
        next_progress_s = time.monotonic() + PROGRESS_EVERY_S
        while not stop.wait(EVENTS_POLL_S):
            recorder.on_events(poller.poll(), time.time_ns())
            if time.monotonic() >= next_progress_s:
                next_progress_s += PROGRESS_EVERY_S
                log.info("recording %s: %d dropped so far", output, sink.dropped)
        recorder.on_events(poller.poll(), time.time_ns())
        for subscriber in subscribers:
            subscriber.undeclare()  # type: ignore[no-untyped-call]  # zenoh stub
    summary = sink.close()
    how = "complete" if summary.complete else f"INCOMPLETE: {summary.dropped} dropped {summary.error or ''}".strip()
    log.info("recording %s closed: %d messages (%s)", output, summary.records, how)
    return summary.records


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=PROG, description="Record every topic of the cell to MCAP (with Foxglove 3D capsules) until Ctrl-C"
    )
    add_config_argument(parser)
    add_zenoh_arguments(parser)
    # a client of the peer it connects to (the gateway by default), which routes every topic of the cell to it
    parser.set_defaults(zenoh_mode="client")
    parser.add_argument(
        "--output", "-o", type=Path, required=True, metavar="PATH",
        help="the MCAP file to write; with --format ros2, the bag folder to create",
    )  # fmt: skip
    parser.add_argument(
        "--format", choices=("json", "ros2"), default="json", dest="output_format",
        help="json: the contract's JSON messages with Foxglove scenes (default); ros2: a ROS 2 bag (MCAP, CDR)",
    )  # fmt: skip
    parser.add_argument(
        "--distro", choices=get_args(Ros2Distro), default=None,
        help="with --format ros2: whose message definitions (default: [ros2] distro of the cell file)",
    )  # fmt: skip
    parser.add_argument(
        "--events-url",
        default=None,
        metavar="URL",
        help="the gateway's HTTP API for its event log (default http://<gateway.http_host>:<gateway.http_port>; "
        "'none': no events)",
    )
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    connect = args.zenoh_connect or ([] if args.zenoh_listen else [DEFAULT_ENDPOINT])
    with stop_on_signals() as stop:
        try:
            config = load_cell_config(args.config)
            zenoh_options = options_from_args(args, RECORDER, config)  # subscribes only (access control)
            events_url = args.events_url or f"http://{config.gateway.http_host}:{config.gateway.http_port}"
            run_recorder(
                config,
                args.output,
                args.zenoh_listen,
                connect,
                stop,
                None if events_url == "none" else events_url,
                zenoh_options=zenoh_options,
                output_format=args.output_format,
                distro=args.distro,
            )
        except (ConfigError, RecordingError) as exc:
            sys.stderr.write(f"{PROG}: {' '.join(str(exc).split())}\n")
            sys.exit(2)
        except zenoh.ZError as exc:
            where = ", ".join(args.zenoh_connect or [DEFAULT_ENDPOINT])
            sys.stderr.write(f"{PROG}: cannot join the cell at {where} (is the gateway running?): {exc}\n")
            sys.exit(2)
    sys.exit(0)


if __name__ == "__main__":
    cli()
