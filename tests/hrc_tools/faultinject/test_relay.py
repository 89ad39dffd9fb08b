"""``hrc-fault-relay``: rule parsing and fates (pure), the delay line, then the relay as a process between
two Zenoh sessions of this test: measured delay, jitter, seeded loss and duplication, reordering, no echo,
partitions (scheduled and by control message), clean exits.
"""

from __future__ import annotations

import json
import random
import signal
import statistics
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, start_program, stop_all, stop_program, wait_or_fail
from hrc_tools.faultinject.delay_line import DelayLine
from hrc_tools.faultinject.rules import FaultRule, RuleError, draw_fate, first_match, parse_rule

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

# -- rules and fates (pure) --------------------------------------------------------------------------


def test_parse_rule_known_answer() -> None:
    rule = parse_rule("hrc/*/tracker/**:delay=0.1,jitter=0.02,loss=0.05,dup=0.01,dir=a2b")
    assert rule == FaultRule(
        "hrc/*/tracker/**", frozenset({"a2b"}), delay_s=0.1, jitter_s=0.02, loss=0.05, dup=0.01, reorder=0.0
    )
    assert parse_rule("hrc/**:reorder=0.5,reorder_delay=0.01").directions == {"a2b", "b2a"}
    assert parse_rule("hrc/**:").delay_s == 0.0


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("no-colon", "expected KEYEXPR:param=value"),
        ("hrc/**:delay", "allowed params"),
        ("hrc/**:speed=3", "allowed params"),
        ("hrc/**:delay=abc", "not a number"),
        ("hrc/**:delay=-0.1", "allowed: 0 to"),
        ("hrc/**:delay=nan", "allowed: 0 to"),
        ("hrc/**:loss=1.5", "probability"),
        ("hrc/**:dir=up", "allowed: a2b, b2a, both"),
        ("hrc//x:delay=1", "not a valid key expression"),
    ],
)
def test_parse_rule_rejects_with_what_is_allowed(text: str, fragment: str) -> None:
    with pytest.raises(RuleError, match=fragment):
        parse_rule(text)


def test_first_matching_rule_wins_per_direction() -> None:
    rules = (parse_rule("hrc/*/robot/*/override:delay=0.2,dir=b2a"), parse_rule("hrc/**:loss=0.1"))
    assert first_match(rules, "hrc/demo/robot/ur5/override", "b2a") is rules[0]
    assert first_match(rules, "hrc/demo/robot/ur5/override", "a2b") is rules[1]
    assert first_match(rules, "other/key", "a2b") is None


def test_fates_follow_the_probabilities_and_the_seed() -> None:
    rule = FaultRule("hrc/**", delay_s=0.1, jitter_s=0.02, loss=0.1, dup=0.05, reorder=0.02, reorder_delay_s=0.03)
    n = 20_000
    fates = [draw_fate(rule, random.Random("7/a2b")) for _ in range(1)]  # same seed, same first fate
    assert fates == [draw_fate(rule, random.Random("7/a2b"))]
    rng = random.Random(1)
    fates = [draw_fate(rule, rng) for _ in range(n)]
    lost = sum(f.lost for f in fates)
    assert lost / n == pytest.approx(0.1, abs=0.01)
    delivered = [f for f in fates if not f.lost]
    assert sum(len(f.offsets_s) == 2 for f in delivered) / len(delivered) == pytest.approx(0.05, abs=0.01)
    assert sum(f.reordered for f in delivered) / len(delivered) == pytest.approx(0.02, abs=0.005)
    plain = [f.offsets_s[0] for f in delivered if not f.reordered]
    assert min(plain) >= 0.08 - 1e-12
    assert max(plain) <= 0.12 + 1e-12
    assert statistics.mean(plain) == pytest.approx(0.1, abs=0.001)
    held = [f.offsets_s[0] for f in delivered if f.reordered]
    assert min(held) >= 0.11 - 1e-12
    assert draw_fate(None, rng).offsets_s == (0.0,)


def test_delay_line_delivers_in_due_order_at_the_due_time() -> None:
    got: list[tuple[int, float]] = []
    start = time.monotonic()
    with DelayLine[int](lambda i: got.append((i, time.monotonic() - start))) as line:
        for i, due in enumerate([0.06, 0.02, 0.04, 0.04, 0.0]):
            line.push(start + due, i)
        deadline = time.monotonic() + 10.0  # how late it delivers is the machine's load: a benchmark's question
        while len(got) < 5 and time.monotonic() < deadline:
            time.sleep(0.005)
        line.push(time.monotonic() + 10.0, 99)  # still pending at exit: discarded
    assert [i for i, _ in got] == [4, 1, 2, 3, 0]
    for i, t in got:
        assert t >= [0.06, 0.02, 0.04, 0.04, 0.0][i]  # never before its due time
    assert line.delivered == 5
    assert line.discarded == 1


# -- the relay process ---------------------------------------------------------------------------------

N = 400
PERIOD_S = 0.004
SEED = 11
RULES = [
    "hrc/t/delay/**:delay=0.1,dir=a2b",
    "hrc/t/jitter/**:delay=0.05,jitter=0.02,dir=a2b",
    "hrc/t/lossy/**:loss=0.2,dup=0.1,dir=a2b",
    "hrc/t/shuffle/**:reorder=0.2,reorder_delay=0.02,dir=a2b",
    "hrc/t/back/**:delay=0.03,dir=b2a",
]
STREAMS = ["delay", "jitter", "lossy", "shuffle", "plain"]


@dataclass
class Received:
    """Samples received by one test session: (key, index, one-way delay [s], receive order)."""

    samples: list[tuple[str, int, float]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_sample(self, sample: zenoh.Sample) -> None:
        now_ns = time.monotonic_ns()
        body = json.loads(sample.payload.to_bytes())
        with self.lock:
            self.samples.append((str(sample.key_expr), int(body["i"]), (now_ns - int(body["t_ns"])) / 1e9))

    def stream(self, key: str) -> list[tuple[int, float]]:
        with self.lock:
            return [(i, d) for k, i, d in self.samples if k == key]


@dataclass
class RelayRun:
    at_b: Received
    at_a: Received
    stats: dict[str, dict[str, int]]
    code: int
    log: str
    partition_sends: list[tuple[int, float]]
    """(index, seconds after the control message) of the messages sent around the partition."""


def _payload(i: int) -> bytes:
    return json.dumps({"i": i, "t_ns": time.monotonic_ns()}).encode()


def _wait_until_linked(a: zenoh.Session, at_b: Received, timeout_s: float = 15.0) -> None:
    """Put probes on side A until one comes out of side B."""

    def linked() -> bool:
        a.put("hrc/t/probe", _payload(-1))
        return bool(at_b.stream("hrc/t/probe"))

    wait_or_fail(linked, timeout_s, "the relay linking the two sessions")


@pytest.fixture(scope="module")
def relay_run(tmp_path_factory: pytest.TempPathFactory) -> RelayRun:
    """One relay; side A sends five streams interleaved (and B one back), then a partition by control message."""
    tmp = tmp_path_factory.mktemp("relay")
    a_ep, b_ep = free_endpoint(), free_endpoint()
    stats_path, log_path = tmp / "stats.json", tmp / "relay.log"
    args = ["--a-listen", a_ep, "--b-connect", b_ep, "--seed", str(SEED), "--stats-json", str(stats_path)]
    proc = start_program("hrc_tools.faultinject", [*args, *(a for r in RULES for a in ("--rule", r))], log_path)
    at_a, at_b = Received(), Received()
    try:
        with zenoh.open(session_config(listen=[b_ep])) as b, zenoh.open(session_config(connect=[a_ep])) as a:
            # Only remote samples: what a session hears of its own puts locally is not the relay's doing.
            b.declare_subscriber("hrc/**", at_b.on_sample, allowed_origin=zenoh.Locality.REMOTE)
            a.declare_subscriber("hrc/**", at_a.on_sample, allowed_origin=zenoh.Locality.REMOTE)
            _wait_until_linked(a, at_b)
            pubs = {
                s: a.declare_publisher(f"hrc/t/{s}/x", congestion_control=zenoh.CongestionControl.BLOCK)
                for s in STREAMS
            }
            back = b.declare_publisher("hrc/t/back/x", congestion_control=zenoh.CongestionControl.BLOCK)
            next_s = time.monotonic()
            for i in range(N):
                for pub in pubs.values():
                    pub.put(_payload(i))
                back.put(_payload(i))
                next_s += PERIOD_S
                time.sleep(max(0.0, next_s - time.monotonic()))
            time.sleep(0.3)
            # Partition by control message: 0.5 s of silence in both directions, then traffic again.
            a.put("hrc/t/faultinject/control", json.dumps({"partition_for_s": 0.5}).encode())
            sends: list[tuple[int, float]] = []
            t0 = time.monotonic()
            while time.monotonic() - t0 < 1.0:
                sends.append((N + len(sends), time.monotonic() - t0))
                pubs["plain"].put(_payload(sends[-1][0]))
                time.sleep(0.01)
            a.put("hrc/t/faultinject/control", b"not json")
            time.sleep(0.3)
        code = stop_program(proc, signal.SIGINT)
    finally:
        stop_all([proc])
    return RelayRun(at_b, at_a, json.loads(stats_path.read_text()), code, log_path.read_text(), sends)


def _figures(delays: list[float]) -> str:
    q = statistics.quantiles(delays, n=20)
    median = statistics.median(delays)
    return f"n {len(delays)}, min {min(delays):.4f}, median {median:.4f}, p95 {q[-1]:.4f}, max {max(delays):.4f} s"


def test_measured_one_way_delay_is_the_configured_one(relay_run: RelayRun) -> None:
    delays = [d for _, d in relay_run.at_b.stream("hrc/t/delay/x")]
    assert len(delays) == N
    # Measured on 2 cores: median 100.5 ms, p99 100.9 ms (the relay itself adds ~0.5 ms).
    assert statistics.median(delays) == pytest.approx(0.1, abs=0.003), _figures(delays)
    assert min(delays) >= 0.1, _figures(delays)  # never early
    assert statistics.quantiles(delays, n=20)[-1] < 0.1 + 0.015, _figures(delays)
    plain = [d for i, d in relay_run.at_b.stream("hrc/t/plain/x") if i < N]
    assert statistics.median(plain) < 0.005, _figures(plain)
    back = [d for _, d in relay_run.at_a.stream("hrc/t/back/x")]
    assert len(back) == N
    assert statistics.median(back) == pytest.approx(0.03, abs=0.003), _figures(back)


def test_jitter_spreads_the_delay_but_keeps_the_order(relay_run: RelayRun) -> None:
    got = relay_run.at_b.stream("hrc/t/jitter/x")
    assert [i for i, _ in got] == list(range(N))
    delays = [d for _, d in got]
    assert min(delays) >= 0.03, _figures(delays)
    # Keeping the order holds a message behind a later-drawn predecessor: the spread leans upward.
    assert statistics.quantiles(delays, n=20)[-1] < 0.07 + 0.015, _figures(delays)
    assert statistics.stdev(delays) > 0.004, _figures(delays)


def _expected_fates(stream: str) -> Counter[str]:
    """Replay the relay's seeded draws: one generator per direction, messages in the order they were put."""
    rules = tuple(parse_rule(r) for r in RULES)
    rng = random.Random(f"{SEED}/a2b")
    counts: Counter[str] = Counter()
    for _ in range(N):
        for s in STREAMS:
            fate = draw_fate(first_match(rules, f"hrc/t/{s}/x", "a2b"), rng)
            if s == stream:
                counts["lost"] += fate.lost
                counts["dup"] += len(fate.offsets_s) == 2
                counts["reordered"] += fate.reordered
    return counts


def test_seeded_loss_and_duplicates(relay_run: RelayRun) -> None:
    got = Counter(i for i, _ in relay_run.at_b.stream("hrc/t/lossy/x"))
    expected = _expected_fates("lossy")
    lost = N - len(got)
    assert lost == expected["lost"]  # the seed fixes the fates
    assert lost / N == pytest.approx(0.2, abs=0.06)
    duplicated = sum(1 for c in got.values() if c == 2)
    assert duplicated == expected["dup"]
    assert duplicated > 0
    assert max(got.values()) <= 2


def test_reordering_lets_later_messages_overtake(relay_run: RelayRun) -> None:
    order = [i for i, _ in relay_run.at_b.stream("hrc/t/shuffle/x")]
    assert sorted(order) == list(range(N))  # nothing lost
    overtaken = sum(1 for k in range(1, len(order)) if order[k] < order[k - 1])
    expected = _expected_fates("shuffle")["reordered"]
    assert expected > 0
    assert 0 < overtaken <= expected
    assert relay_run.stats["a2b"]["reordered"] >= expected


def test_no_echo_each_side_hears_only_the_other(relay_run: RelayRun) -> None:
    keys_at_a = {k for k, _, _ in relay_run.at_a.samples}
    keys_at_b = {k for k, _, _ in relay_run.at_b.samples}
    assert keys_at_a == {"hrc/t/back/x"}
    assert "hrc/t/back/x" not in keys_at_b
    assert "hrc/t/faultinject/control" not in keys_at_b  # control messages are not forwarded
    # What the relay took from each side is exactly what that side put (nothing came back round).
    assert relay_run.stats["b2a"]["received"] == N
    assert relay_run.stats["a2b"]["received"] >= len(STREAMS) * N


def test_partition_by_control_message_drops_then_heals(relay_run: RelayRun) -> None:
    through = {i for i, _ in relay_run.at_b.stream("hrc/t/plain/x") if i >= N}
    # The partition starts when the relay takes the control message (a few ms after the put) and lasts 0.5 s.
    inside = [i for i, t in relay_run.partition_sends if 0.1 <= t <= 0.45]
    healed = [i for i, t in relay_run.partition_sends if t >= 0.7]
    assert inside
    assert not through & set(inside), relay_run.log
    assert set(healed) <= through, relay_run.log
    assert relay_run.stats["a2b"]["partitioned"] > 20
    assert relay_run.stats["control_messages"] == 1
    assert relay_run.stats["control_rejected"] == 1
    assert relay_run.code == 0


def test_scheduled_partition_and_sigterm(tmp_path: Path) -> None:
    a_ep, b_ep = free_endpoint(), free_endpoint()
    stats_path = tmp_path / "stats.json"
    proc = start_program(
        "hrc_tools.faultinject",
        [
            *("--a-connect", a_ep, "--b-listen", b_ep),
            *("--partition-after-s", "1.5", "--partition-for-s", "1.0", "--stats-json", str(stats_path)),
        ],
        tmp_path / "relay.log",
    )
    at_b = Received()
    try:
        with zenoh.open(session_config(connect=[b_ep])) as b, zenoh.open(session_config(listen=[a_ep])) as a:
            b.declare_subscriber("hrc/**", at_b.on_sample, allowed_origin=zenoh.Locality.REMOTE)
            _wait_until_linked(a, at_b)
            t0 = time.monotonic()
            sent: list[tuple[int, float]] = []
            i = 0
            while time.monotonic() - t0 < 3.5:
                a.put("hrc/t/part", _payload(i))
                sent.append((i, time.monotonic() - t0))
                i += 1
                time.sleep(0.01)
            time.sleep(0.2)
        code = stop_program(proc, signal.SIGTERM)
    finally:
        stop_all([proc])
    got = {i for i, _ in at_b.stream("hrc/t/part")}
    missing_i = [i for i, _ in sent if i not in got]
    missing = [t for i, t in sent if i not in got]
    assert code == 0
    assert missing, "the partition dropped nothing"
    # One silent stretch, somewhere in the 3.5 s (the relay's clock started before the probes): every probe
    # between the first and the last dropped one was dropped, nothing else. How long it lasted in the sender's
    # clock depends on the machine's load (a stalled relay drops what queued before the partition began); the
    # bound only says that a 1 s partition is not a much longer one.
    assert missing_i == list(range(missing_i[0], missing_i[-1] + 1))
    assert max(missing) - min(missing) < 2.0
    stats = json.loads(stats_path.read_text())
    assert stats["a2b"]["partitioned"] == len(missing)


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--a-listen", "tcp/127.0.0.1:1", "--rule", "hrc/**:loss=2"], "probability"),
        (["--a-listen", "tcp/127.0.0.1:1"], "side B has no endpoint"),
        (["--a-listen", "tcp/127.0.0.1:1", "--b-connect", "nonsense"], "cannot open the side"),
    ],
)
def test_invalid_options_exit_2_with_one_line(args: list[str], fragment: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "hrc_tools.faultinject", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO_ROOT,
    )
    assert result.returncode == 2, result.stderr
    # plain TCP (the test harness's) is logged as a WARNING first; the reason is one line of its own
    lines = [line for line in result.stderr.strip().splitlines() if " WARNING INSECURE " not in line]
    assert len(lines) == 1, result.stderr
    assert fragment in lines[0]
