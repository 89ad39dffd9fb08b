"""``hrc-fault-relay``: a Zenoh relay between two sessions that delays, jitters, drops, duplicates and
reorders real traffic, per key expression and direction, and can cut the link for a while (partition).

    program(s) ──► side A session ──[rules, delay line]──► side B session ──► program(s)
               ◄──                ◄──[rules, delay line]──                ◄──

Each side is its own peer session (``--a-listen``/``--a-connect``, ``--b-listen``/``--b-connect``). Zenoh
peers do not route for each other, so a program that reaches the other side only through the relay sees
exactly what the relay lets through. The subscribers take only remote samples
(``allowed_origin=Locality.REMOTE``) and the relay publishes only to remote peers
(``allowed_destination=Locality.REMOTE``), so a forwarded message is never picked up again by the relay
and never echoed back to the side it came from.

Callbacks only draw the message's fate (:mod:`hrc_tools.faultinject.rules`) and push it into a
:class:`~hrc_tools.faultinject.delay_line.DelayLine`; its thread publishes at the due time on the monotonic clock.

Partition: ``--partition-after-s T --partition-for-s D`` drops every message in both directions from T to
T + D seconds after start; at run time, a put on the control key (default ``hrc/*/faultinject/control``,
never forwarded) with ``{"partition_for_s": D}`` (optionally ``"dir": "a2b" | "b2a" | "both"``) starts one
now, and ``{"heal": true}`` ends them all. A message is dropped if the link is cut when it arrives or when
it is due.
"""

from __future__ import annotations

import argparse
import json
import logging
import random
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import zenoh

from hrc_contract.config import ConfigError
from hrc_contract.errors import HrcError
from hrc_runtime.cli import add_security_arguments
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import configure_logging
from hrc_runtime.memory import configure_heap
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import PLAIN_TCP_LOOPBACK, SessionOptions, options_from_args, session_config
from hrc_tools.faultinject.delay_line import DelayLine
from hrc_tools.faultinject.rules import DIRECTIONS, Direction, FaultRule, RuleError, draw_fate, first_match, parse_rule

PROG = "hrc-fault-relay"
DEFAULT_FORWARD = "hrc/**"
DEFAULT_CONTROL_KEY = "hrc/*/faultinject/control"
PROGRESS_EVERY_S = 5.0
_CACHE_LIMIT = 10_000
"""Key lookups cached per direction; the cache is cleared beyond this (a flood of distinct keys)."""

log = logging.getLogger(PROG)


class RelayError(HrcError):
    """The relay cannot start (bad endpoint, bad option). The message is one line."""


@dataclass(frozen=True)
class RelayConfig:
    """Everything the relay needs; built from the command line or by a test.

    Attributes:
        a_listen, a_connect, b_listen, b_connect: Zenoh endpoints of side A and side B.
        forward: key expressions forwarded in both directions.
        rules: fault rules, first match wins.
        seed: seed of the random fates (one generator per direction).
        partition_after_s, partition_for_s: a partition of both directions from this long after start,
            for this long [s]; None: no scheduled partition.
        control_key: key expression of run-time control messages (never forwarded).
        zenoh_options: both sides' mutual TLS (as ``relay``, a forwarder) and access control.
    """

    a_listen: tuple[str, ...] = ()
    a_connect: tuple[str, ...] = ()
    b_listen: tuple[str, ...] = ()
    b_connect: tuple[str, ...] = ()
    forward: tuple[str, ...] = (DEFAULT_FORWARD,)
    rules: tuple[FaultRule, ...] = ()
    seed: int = 0
    partition_after_s: float | None = None
    partition_for_s: float = 0.0
    control_key: str = DEFAULT_CONTROL_KEY
    zenoh_options: SessionOptions = PLAIN_TCP_LOOPBACK


@dataclass
class DirectionStats:
    """What happened to the messages of one direction.

    Attributes:
        received: samples taken from the source side (control messages excluded).
        forwarded: puts and deletes published on the other side (duplicates included).
        lost: dropped by a ``loss`` rule.
        duplicated: messages delivered twice.
        reordered: messages held back so that later ones overtake them.
        partitioned: dropped because the link was cut (at arrival or when due).
        errors: failed publications.
    """

    received: int = 0
    forwarded: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    partitioned: int = 0
    errors: int = 0


@dataclass
class RelayStats:
    directions: dict[str, DirectionStats] = field(default_factory=lambda: {d: DirectionStats() for d in DIRECTIONS})
    control_messages: int = 0
    control_rejected: int = 0
    max_lateness_s: float = 0.0
    discarded_at_exit: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            **{d: asdict(s) for d, s in self.directions.items()},
            "control_messages": self.control_messages,
            "control_rejected": self.control_rejected,
            "max_lateness_s": round(self.max_lateness_s, 6),
            "discarded_at_exit": self.discarded_at_exit,
        }


class Partitions:
    """Time windows in which a direction of the link is cut (monotonic seconds). Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._windows: list[tuple[float, float, frozenset[Direction]]] = []

    def add(self, start_s: float, end_s: float, directions: frozenset[Direction] = frozenset(DIRECTIONS)) -> None:
        with self._lock:
            self._windows.append((start_s, end_s, directions))

    def heal(self) -> None:
        with self._lock:
            self._windows.clear()

    def active(self, direction: Direction, now_s: float) -> bool:
        with self._lock:
            return any(start <= now_s < end and direction in dirs for start, end, dirs in self._windows)


class _Message(NamedTuple):
    direction: Direction
    key: str
    payload: bytes
    delete: bool
    encoding: zenoh.Encoding
    attachment: bytes | None
    priority: zenoh.Priority
    congestion_control: zenoh.CongestionControl
    express: bool


def _open(listen: Sequence[str], connect: Sequence[str], side: str, options: SessionOptions) -> zenoh.Session:
    try:
        return zenoh.open(session_config(listen, connect, options))
    except zenoh.ZError as exc:
        reason = str(exc).split(" at /", 1)[0]
        raise RelayError(
            f"cannot open the side {side} session (listen {list(listen)}, connect {list(connect)}): {reason}"
        ) from None


class _Forwarder:
    """The relay's moving parts between the two sessions: fates, order, partitions, statistics."""

    def __init__(
        self,
        config: RelayConfig,
        targets: dict[Direction, zenoh.Session],
        line_push: Callable[[float, _Message], None],
        partitions: Partitions,
        stats: RelayStats,
    ) -> None:
        self._config = config
        self._targets = targets
        self._push = line_push
        self._partitions = partitions
        self._stats = stats
        self._lock = threading.Lock()
        self._rngs = {d: random.Random(f"{config.seed}/{d}") for d in DIRECTIONS}
        self._last_due: dict[tuple[Direction, str], float] = {}
        self._rule_cache: dict[tuple[Direction, str], FaultRule | None] = {}
        self._control_cache: dict[str, bool] = {}
        self._control_ke = zenoh.KeyExpr(config.control_key)

    def _is_control(self, key: str) -> bool:
        hit = self._control_cache.get(key)
        if hit is None:
            if len(self._control_cache) > _CACHE_LIMIT:
                self._control_cache.clear()
            hit = self._control_cache[key] = self._control_ke.includes(key)
        return hit

    def _rule(self, direction: Direction, key: str) -> FaultRule | None:
        cache_key = (direction, key)
        if cache_key not in self._rule_cache:
            if len(self._rule_cache) > _CACHE_LIMIT:
                self._rule_cache.clear()
            self._rule_cache[cache_key] = first_match(self._config.rules, key, direction)
        return self._rule_cache[cache_key]

    def on_sample(self, direction: Direction, sample: zenoh.Sample) -> None:
        """Subscriber callback: draw the fate and schedule the copies. Never sleeps."""
        now_s = time.monotonic()
        key = str(sample.key_expr)
        if self._is_control(key):
            return
        attachment = sample.attachment
        message = _Message(
            direction,
            key,
            sample.payload.to_bytes(),
            sample.kind == zenoh.SampleKind.DELETE,
            sample.encoding,
            None if attachment is None else attachment.to_bytes(),
            sample.priority,
            sample.congestion_control,
            sample.express,
        )
        stats = self._stats.directions[direction]
        with self._lock:
            stats.received += 1
            if self._partitions.active(direction, now_s):
                stats.partitioned += 1
                return
            fate = draw_fate(self._rule(direction, key), self._rngs[direction])
            if fate.lost:
                stats.lost += 1
                return
            due_s = now_s + fate.offsets_s[0]
            if fate.reordered:
                stats.reordered += 1
            else:  # keep the key's order in this direction despite jitter
                due_s = max(due_s, self._last_due.get((direction, key), due_s))
                if len(self._last_due) > _CACHE_LIMIT:
                    self._last_due.clear()
                self._last_due[(direction, key)] = due_s
            if len(fate.offsets_s) > 1:
                stats.duplicated += 1
            for offset_s in fate.offsets_s:
                self._push(max(due_s, now_s + offset_s), message)

    def deliver(self, message: _Message) -> None:
        """Delay line callback: publish on the other side, unless the link is cut now."""
        stats = self._stats.directions[message.direction]
        if self._partitions.active(message.direction, time.monotonic()):
            with self._lock:
                stats.partitioned += 1
            return
        target = self._targets[message.direction]
        try:
            if message.delete:
                target.delete(
                    message.key,
                    congestion_control=message.congestion_control,
                    priority=message.priority,
                    express=message.express,
                    attachment=message.attachment,
                )
            else:
                target.put(
                    message.key,
                    message.payload,
                    encoding=message.encoding,
                    congestion_control=message.congestion_control,
                    priority=message.priority,
                    express=message.express,
                    attachment=message.attachment,
                    allowed_destination=zenoh.Locality.REMOTE,
                )
        except zenoh.ZError:
            with self._lock:
                stats.errors += 1
            raise
        with self._lock:
            stats.forwarded += 1

    def on_control(self, sample: zenoh.Sample) -> None:
        """Control callback: ``{"partition_for_s": D[, "dir": ...]}`` or ``{"heal": true}``."""
        now_s = time.monotonic()
        try:
            command = json.loads(sample.payload.to_bytes())
            if not isinstance(command, dict):
                raise ValueError("expected a JSON object")
            if command.get("heal") is True:
                self._partitions.heal()
                log.warning("control: partition healed")
            else:
                duration_s = float(command["partition_for_s"])
                if not 0.0 < duration_s <= 3600.0:
                    raise ValueError(f"partition_for_s = {duration_s}; allowed: (0, 3600] s")
                dirs_text = command.get("dir", "both")
                if dirs_text not in (*DIRECTIONS, "both"):
                    raise ValueError(f"dir = {dirs_text!r}; allowed: a2b, b2a, both")
                dirs: frozenset[Direction] = frozenset(DIRECTIONS) if dirs_text == "both" else frozenset({dirs_text})
                self._partitions.add(now_s, now_s + duration_s, dirs)
                log.warning("control: partition (%s) for %.3f s", dirs_text, duration_s)
        except (ValueError, KeyError, TypeError) as exc:
            with self._lock:
                self._stats.control_rejected += 1
            log.warning("control message rejected: %s", str(exc)[:200])
            return
        with self._lock:
            self._stats.control_messages += 1


def _progress(stats: RelayStats, pending: int) -> str:
    parts = [
        f"{d}: {s.received} in, {s.forwarded} out, {s.lost} lost, {s.duplicated} dup, {s.reordered} reordered, "
        f"{s.partitioned} partitioned"
        for d, s in stats.directions.items()
    ]
    return "; ".join(parts) + f"; {pending} pending"


def run_relay(config: RelayConfig, stop: threading.Event) -> RelayStats:
    """Relay between the two sides until ``stop`` is set. Returns what happened.

    Raises:
        RelayError: a side has no endpoint, or a session cannot be opened.
    """
    for side, listen, connect in (("A", config.a_listen, config.a_connect), ("B", config.b_listen, config.b_connect)):
        if not listen and not connect:
            raise RelayError(
                f"side {side} has no endpoint; allowed: --{side.lower()}-listen and/or --{side.lower()}-connect"
            )
    stats = RelayStats()
    partitions = Partitions()
    with (
        _open(config.a_listen, config.a_connect, "A", config.zenoh_options) as session_a,
        _open(config.b_listen, config.b_connect, "B", config.zenoh_options) as session_b,
    ):
        start_s = time.monotonic()
        if config.partition_after_s is not None and config.partition_for_s > 0.0:
            partitions.add(
                start_s + config.partition_after_s, start_s + config.partition_after_s + config.partition_for_s
            )
        targets: dict[Direction, zenoh.Session] = {"a2b": session_b, "b2a": session_a}
        sources: dict[Direction, zenoh.Session] = {"a2b": session_a, "b2a": session_b}
        forwarder: _Forwarder
        line: DelayLine[_Message] = DelayLine(lambda m: forwarder.deliver(m), name="relay-delay-line")
        forwarder = _Forwarder(config, targets, line.push, partitions, stats)
        with line:
            subscribers = []
            for direction, source in sources.items():
                for key_expr in config.forward:
                    subscribers.append(
                        source.declare_subscriber(
                            key_expr,
                            _sample_callback(forwarder, direction),
                            allowed_origin=zenoh.Locality.REMOTE,
                        )
                    )
                subscribers.append(
                    source.declare_subscriber(
                        config.control_key, _control_callback(forwarder), allowed_origin=zenoh.Locality.REMOTE
                    )
                )
            log.info(
                "relaying %s between A (listen %s, connect %s) and B (listen %s, connect %s); rules: %s%s",
                ", ".join(config.forward),
                list(config.a_listen),
                list(config.a_connect),
                list(config.b_listen),
                list(config.b_connect),
                "; ".join(_describe(rule) for rule in config.rules) or "none",
                ""
                if config.partition_after_s is None
                else f"; partition after {config.partition_after_s} s for {config.partition_for_s} s",
            )
            next_progress_s = start_s + PROGRESS_EVERY_S
            while not stop.wait(max(0.0, next_progress_s - time.monotonic())):
                next_progress_s += PROGRESS_EVERY_S
                log.info(_progress(stats, line.pending()))
            for subscriber in subscribers:
                subscriber.undeclare()  # type: ignore[no-untyped-call]  # zenoh stub
        stats.max_lateness_s = line.max_lateness_s
        stats.discarded_at_exit = line.discarded
    log.info("stopped; %s; max lateness %.4f s", _progress(stats, stats.discarded_at_exit), stats.max_lateness_s)
    return stats


def _sample_callback(forwarder: _Forwarder, direction: Direction) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        try:
            forwarder.on_sample(direction, sample)
        except Exception:  # a callback must never die
            log.exception("error while relaying a sample (%s)", direction)

    return on_sample


def _control_callback(forwarder: _Forwarder) -> Callable[[zenoh.Sample], None]:
    def on_control(sample: zenoh.Sample) -> None:
        try:
            forwarder.on_control(sample)
        except Exception:
            log.exception("error while handling a control message")

    return on_control


def _describe(rule: FaultRule) -> str:
    dirs = "both" if len(rule.directions) == len(DIRECTIONS) else next(iter(rule.directions))
    return (
        f"{rule.key_expr} ({dirs}): delay {rule.delay_s:g} s ± {rule.jitter_s:g} s, loss {rule.loss:g}, "
        f"dup {rule.dup:g}, reorder {rule.reorder:g} (+{rule.reorder_delay_s:g} s)"
    )


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Zenoh relay between two sessions (side A and side B) that injects delay, jitter, loss, "
        "duplication, reordering and partitions on real traffic, per key expression and direction.",
        epilog="Rules: KEYEXPR:param=value,... with params delay [s], jitter [s], loss, dup, reorder "
        "(probabilities), reorder_delay [s], dir=a2b|b2a|both; e.g. "
        "'hrc/*/tracker/**:delay=0.1,jitter=0.02,loss=0.05,dup=0.01'. First matching rule wins. "
        'Run-time control: put {"partition_for_s": D, "dir": "both"} or {"heal": true} on the control key. '
        "Exits 0 on SIGINT/SIGTERM, 2 on invalid options.",
    )
    for side in ("a", "b"):
        for verb in ("listen", "connect"):
            parser.add_argument(
                f"--{side}-{verb}",
                action="append",
                default=[],
                metavar="ENDPOINT",
                help=f"Zenoh endpoint that side {side.upper()} {verb}s {'on' if verb == 'listen' else 'to'}, "
                "e.g. tcp/127.0.0.1:7448 (repeatable)",
            )
    parser.add_argument(
        "--forward",
        action="append",
        default=[],
        metavar="KEYEXPR",
        help=f"key expression to relay in both directions (repeatable; default {DEFAULT_FORWARD})",
    )
    parser.add_argument("--rule", action="append", default=[], metavar="RULE", help="fault rule (repeatable)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random fates (default 0)")
    parser.add_argument(
        "--partition-after-s", type=float, default=None, metavar="T", help="cut the link T s after start"
    )
    parser.add_argument("--partition-for-s", type=float, default=0.0, metavar="D", help="... for D s")
    parser.add_argument(
        "--control-key",
        default=DEFAULT_CONTROL_KEY,
        metavar="KEYEXPR",
        help=f"key expression of run-time control messages, never forwarded (default {DEFAULT_CONTROL_KEY})",
    )
    parser.add_argument("--stats-json", default=None, metavar="PATH", help="write the statistics here at exit")
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    parser.add_argument("--config", default=None, metavar="PATH", help="cell (its access control); default cell.toml")
    add_security_arguments(parser)
    return parser


def config_from_args(args: argparse.Namespace) -> RelayConfig:
    """The relay configuration of parsed command-line arguments.

    Raises:
        RelayError: an invalid rule, key expression or partition time.
    """
    try:
        rules = tuple(parse_rule(text) for text in args.rule)
    except RuleError as exc:
        raise RelayError(str(exc)) from None
    forward = tuple(args.forward) or (DEFAULT_FORWARD,)
    for key_expr in (*forward, args.control_key):
        try:
            zenoh.KeyExpr(key_expr)
        except (zenoh.ZError, ValueError) as exc:
            raise RelayError(f"{key_expr!r} is not a valid key expression: {str(exc).split(' at /', 1)[0]}") from None
    after, duration = args.partition_after_s, args.partition_for_s
    if after is not None and not (0.0 <= after < 1e6 and 0.0 < duration < 1e6):
        raise RelayError(
            f"--partition-after-s {after} --partition-for-s {duration}; allowed: T >= 0 with D > 0 (seconds)"
        )
    endpoints = [*args.a_listen, *args.a_connect, *args.b_listen, *args.b_connect]
    try:  # mutual TLS as ``relay`` and the cell's access control, unless --insecure-plain-tcp on loopback
        options = options_from_args(
            args, "relay", load_cell_config(args.config), endpoints, [*args.a_listen, *args.b_listen]
        )
    except ConfigError as exc:
        raise RelayError(str(exc)) from None
    return RelayConfig(
        a_listen=tuple(args.a_listen),
        a_connect=tuple(args.a_connect),
        b_listen=tuple(args.b_listen),
        b_connect=tuple(args.b_connect),
        forward=forward,
        rules=rules,
        seed=args.seed,
        partition_after_s=after,
        partition_for_s=duration if after is not None else 0.0,
        control_key=args.control_key,
        zenoh_options=options if endpoints else PLAIN_TCP_LOOPBACK,
    )


def main(config: RelayConfig, stop: threading.Event, stats_json: Path | None = None) -> int:
    """Run the relay until ``stop`` is set; write the statistics to ``stats_json``. Returns the exit code.

    Raises:
        RelayError: see :func:`run_relay`.
    """
    stats = run_relay(config, stop)
    if stats_json is not None:
        stats_json.write_text(json.dumps(stats.to_dict(), indent=2) + "\n")
    return 0


def cli(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    configure_logging(args.log_level)
    configure_heap(log)  # before the program's threads start: arenas, heap report on SIGUSR1 (hrc_runtime/memory.py)
    with stop_on_signals() as stop:
        try:
            code = main(config_from_args(args), stop, Path(args.stats_json) if args.stats_json else None)
        except RelayError as exc:
            sys.stderr.write(f"{PROG}: invalid configuration: {' '.join(str(exc).split())}\n")
            sys.exit(2)
    sys.exit(code)


if __name__ == "__main__":
    cli()
