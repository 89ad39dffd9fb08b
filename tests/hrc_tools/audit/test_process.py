"""The ``hrc-audit`` process: the truth auditor fed by hand (no network), then the program over loopback
Zenoh with the test playing the controller and the tracker: summary, JSON and exit codes.
"""

from __future__ import annotations

import json
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pytest
import support.status_examples as ex
import zenoh
from support.paths import REPO_ROOT

from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import Capsule, Human, Humans, JointState, to_payload
from hrc_devices.robots.model import RobotModel
from hrc_runtime.zenoh_session import SessionOptions, session_config
from hrc_tools.audit.main import (
    EXIT_INCONCLUSIVE,
    EXIT_OK,
    EXIT_VIOLATION,
    MAX_HUMAN_TRUTH_GAP_S,
    TruthAuditor,
    exit_code,
    format_report,
)
from hrc_tools.cell.procs import Program, free_endpoint, start_program, stop_all, stop_program, wait_or_fail

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

START_NS = 1_790_000_000_000_000_000
CYCLE_NS = 4_000_000
Q_PICK_ABOVE = [-0.854, -1.353, 1.668, -1.886, -1.571, -0.853]  # tool0 at (0.45, -0.35, 1.10) m
QD = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # the base turns: the tool moves at ~0.57 m/s
STATE_KEY = keys.truth_robot_state("demo", "ur5")


def state(seq: int, stamp_ns: int, override: float = 1.0, q: list[float] | None = None) -> bytes:
    qd = [override * v for v in QD]
    return to_payload(
        JointState(
            robot="ur5",
            seq=seq,
            stamp_ns=stamp_ns,
            q=q or Q_PICK_ABOVE,
            qd=qd,
            qd_nominal=QD,
            override=override,
            override_seq=seq,
            mode="running" if override > 0 else "stopped",
        )
    )


def humans(seq: int, stamp_ns: int, at: tuple[float, float, float] | None, radius_m: float = 0.1) -> bytes:
    people = [] if at is None else [Human(id="h1", capsules=[Capsule(name="hand_r", a=at, b=at, radius=radius_m)])]
    return to_payload(Humans(tracker="truth", seq=seq, stamp_ns=stamp_ns, humans=people))


@pytest.fixture
def auditor(cell_config: CellConfig, ur5: RobotModel) -> TruthAuditor:
    return TruthAuditor(cell_config, {"ur5": ur5}, START_NS)


def feed(auditor: TruthAuditor, n: int, human_at: tuple[float, float, float] | None, **kwargs: float) -> None:
    """``n`` controller cycles with a true humans sample at every cycle's stamp."""
    for k in range(n):
        stamp = START_NS + k * CYCLE_NS
        auditor.on_truth_humans(humans(k + 1, stamp, human_at))
        auditor.on_truth_state(STATE_KEY, state(k, stamp, **kwargs))
    auditor.process()


def test_far_human_moving_robot_passes(auditor: TruthAuditor) -> None:
    feed(auditor, 50, (4.0, 0.0, 1.0))
    report = auditor.report(1.0)
    r = report["robots"]["ur5"]
    assert r["cycles"] == 50
    assert r["violations"] == 0
    # 4 m away less the radii, less what a stop from full speed lets the human (K t_b) and the tool cover.
    assert 2.5 < r["smallest_margin_m"] < r["min_distance_m"] - 1.6 * 0.24
    assert r["duration_s"] == pytest.approx(50 * 0.004)
    assert exit_code(report) == EXIT_OK
    assert report["verdict"] == "pass"
    assert report["backlog_max"] == 50  # feed() processes once, after all 50 states


def test_the_largest_backlog_is_reported_not_the_last(auditor: TruthAuditor) -> None:
    feed(auditor, 30, (4.0, 0.0, 1.0))
    feed(auditor, 5, (4.0, 0.0, 1.0))
    assert auditor.report(1.0)["backlog_max"] == 30


def test_human_at_the_moving_tool_is_a_violation_and_contact(auditor: TruthAuditor) -> None:
    feed(auditor, 10, (0.45, -0.35, 1.15))
    report = auditor.report(1.0)
    r = report["robots"]["ur5"]
    assert r["violations"] == 10
    assert r["contacts_while_moving"] == 10
    assert r["smallest_margin_m"] < 0.0
    assert r["smallest_margin_pair"][1] == "truth/h1/hand_r"
    assert exit_code(report) == EXIT_VIOLATION
    assert "VIOLATION" in format_report(report)


def test_a_stopped_robot_touched_is_no_violation(auditor: TruthAuditor) -> None:
    feed(auditor, 10, (0.45, -0.35, 1.15), override=0.0)
    r = auditor.report(1.0)["robots"]["ur5"]
    assert r["violations"] == 0
    assert r["min_distance_m"] == 0.0
    assert r["time_stopped_s"] == pytest.approx(10 * 0.004)


def test_the_age_of_the_human_truth_shrinks_the_margin_conservatively(cell_config: CellConfig, ur5: RobotModel) -> None:
    margins = []
    for age_ns in (0, 20_000_000, -20_000_000):  # truth 20 ms older, then 20 ms newer than the state
        auditor = TruthAuditor(cell_config, {"ur5": ur5}, START_NS)
        auditor.on_truth_humans(humans(1, START_NS - age_ns, (0.9, -0.35, 1.1)))
        auditor.on_truth_state(STATE_KEY, state(0, START_NS))
        auditor.process()
        r = auditor.report(1.0)["robots"]["ur5"]
        assert r["cycles"] == 1
        margins.append(r["smallest_margin_m"])
        assert r["max_human_truth_age_s"] == pytest.approx(abs(age_ns) / 1e9)
    k = cell_config.safety.human_speed_mps
    assert margins[0] - margins[1] == pytest.approx(k * 0.02, abs=1e-9)
    assert margins[0] - margins[2] == pytest.approx(k * 0.02, abs=1e-9)


def test_the_nearest_truth_sample_is_used(auditor: TruthAuditor) -> None:
    auditor.on_truth_humans(humans(1, START_NS, (0.45, -0.35, 1.15)))  # touching
    auditor.on_truth_humans(humans(2, START_NS + 50_000_000, (4.0, 0.0, 1.0)))  # far, 50 ms later
    auditor.on_truth_state(STATE_KEY, state(0, START_NS + 10_000_000))  # nearest: the touching one
    auditor.on_truth_state(STATE_KEY, state(1, START_NS + 45_000_000))  # nearest: the far one
    auditor.process()
    r = auditor.report(1.0)["robots"]["ur5"]
    assert r["cycles"] == 2
    assert r["violations"] == 1
    assert r["truth_gap_cycles"] == 0


def test_across_a_gap_in_the_truth_the_people_last_seen_grow_by_k_times_the_gap(
    cell_config: CellConfig, ur5: RobotModel
) -> None:
    """A person no longer seen is somewhere within K · age of where they were last, not gone: the margin shrinks by
    exactly that, and a gap long enough turns a pass into a violation."""
    k = cell_config.safety.human_speed_mps
    gap_s = MAX_HUMAN_TRUTH_GAP_S + 0.05
    margins, violations = [], []
    for age_s in (0.0, gap_s, 2.0):
        auditor = TruthAuditor(cell_config, {"ur5": ur5}, START_NS)
        auditor.on_truth_humans(humans(1, START_NS, (1.6, -0.35, 1.1)))
        auditor.on_truth_state(STATE_KEY, state(0, START_NS + int(age_s * 1e9)))
        auditor.process()
        r = auditor.report(1.0)["robots"]["ur5"]
        assert r["cycles"] == 1
        assert r["unaudited_cycles"] == 0
        assert r["truth_gap_cycles"] == (1 if age_s > MAX_HUMAN_TRUTH_GAP_S else 0)
        margins.append(r["smallest_margin_m"])
        violations.append(r["violations"])
    assert margins[0] - margins[1] == pytest.approx(k * gap_s, abs=1e-9)
    assert violations == [0, 0, 1]  # 2 s at K: the person may be at the tool
    assert margins[0] > 0.0 > margins[2]


def test_across_a_gap_the_sample_before_is_used_not_the_one_after(auditor: TruthAuditor) -> None:
    """The sample after a gap can be a world that started over (a restarted tracker plays its scenario from the
    beginning): the cycles in the gap are judged against where the people were last, grown."""
    auditor.on_truth_humans(humans(1, START_NS, (0.45, -0.35, 1.15)))  # touching the tool
    auditor.on_truth_humans(humans(2, START_NS + 450_000_000, (4.0, 0.0, 1.0)))  # far, after a 0.45 s gap
    auditor.on_truth_state(STATE_KEY, state(0, START_NS + 300_000_000))  # nearer to the far one, in the gap
    auditor.process()
    r = auditor.report(1.0)["robots"]["ur5"]
    assert r["truth_gap_cycles"] == 1
    assert r["longest_truth_gap_s"] == pytest.approx(0.3)
    assert r["violations"] == 1
    assert "judged across a gap in the human truth" in format_report(auditor.report(1.0))


def test_a_state_waits_for_the_truth_of_its_time_before_it_is_judged_across_a_gap(auditor: TruthAuditor) -> None:
    """Truth late on its way is not a gap: the state waits for it (up to ``settle_s``), then is judged against it."""
    auditor.on_truth_humans(humans(1, START_NS, (0.45, -0.35, 1.15)))  # touching the tool
    auditor.on_truth_state(STATE_KEY, state(0, START_NS + 200_000_000))  # its own truth not here yet
    assert auditor.process(settle_s=60.0) == 0
    auditor.on_truth_humans(humans(2, START_NS + 200_000_000, (4.0, 0.0, 1.0)))  # it arrives: far
    assert auditor.process(settle_s=60.0) == 1
    r = auditor.report(1.0)["robots"]["ur5"]
    assert (r["cycles"], r["violations"], r["truth_gap_cycles"]) == (1, 0, 0)


def test_without_waiting_the_same_state_is_judged_across_the_gap(auditor: TruthAuditor) -> None:
    auditor.on_truth_humans(humans(1, START_NS, (0.45, -0.35, 1.15)))
    auditor.on_truth_state(STATE_KEY, state(0, START_NS + 200_000_000))
    assert auditor.process(settle_s=0.0) == 1
    r = auditor.report(1.0)["robots"]["ur5"]
    assert (r["cycles"], r["violations"], r["truth_gap_cycles"]) == (1, 1, 1)


def test_a_state_older_than_all_truth_is_not_audited(auditor: TruthAuditor) -> None:
    auditor.on_truth_humans(humans(1, START_NS + 500_000_000, (4.0, 0.0, 1.0)))
    auditor.on_truth_state(STATE_KEY, state(0, START_NS))
    auditor.process()
    r = auditor.report(1.0)["robots"]["ur5"]
    assert r["cycles"] == 0
    assert r["unaudited_cycles"] == 1


def test_without_any_human_truth_nothing_is_audited(auditor: TruthAuditor) -> None:
    for k in range(5):
        auditor.on_truth_state(STATE_KEY, state(k, START_NS + k * CYCLE_NS))
    auditor.process()
    report = auditor.report(1.0)
    assert report["cycles_audited"] == 0
    assert report["robots"]["ur5"]["unaudited_cycles"] == 5
    assert exit_code(report) == EXIT_INCONCLUSIVE
    assert report["verdict"] == "inconclusive"


def test_zones_program_cycles_gaps_and_rejections(auditor: TruthAuditor) -> None:
    status = ex.gateway_status(START_NS, ur5=ex.robot_status(delta=0.5, zone="reduced_speed", t_delay_s=0.12))
    auditor.on_status(status.model_dump_json().encode())
    auditor.on_emu_stats("ur5", json.dumps({"robot": "ur5", "cycles_completed": 7}).encode())
    for k in (0, 1, 2, 5):  # seq 3 and 4 lost
        stamp = START_NS + k * CYCLE_NS
        auditor.on_truth_humans(humans(k + 1, stamp, None))
        auditor.on_truth_state(STATE_KEY, state(k, stamp))
    for payload in (b"not json", b'{"schema": "hrc.joint_state/1"}', b"\xff"):
        auditor.on_truth_state(STATE_KEY, payload)
        auditor.on_truth_humans(payload)
        auditor.on_status(payload)
        auditor.on_emu_stats("ur5", payload)
    auditor.on_truth_state(keys.truth_robot_state("demo", "ghost"), state(9, START_NS))
    auditor.process()
    report = auditor.report(1.0)
    r = report["robots"]["ur5"]
    assert r["time_in_zone_s"] == {"reduced_speed": pytest.approx(4 * 0.004 + 2 * 0.004)}
    assert r["program_cycles_completed"] == 7
    assert r["truth_gaps"] == 2
    assert r["smallest_margin_m"] is None  # nobody present: the margin is infinite
    assert r["gateway"]["t_delay_s_median"] == 0.12
    assert report["rejected"]["truth_state/unknown_robot"] == 1
    assert sum(v for k, v in report["rejected"].items() if k.startswith("truth_humans/")) == 3
    assert report["rejected"]["status/invalid"] == 3
    assert report["rejected"]["emu_stats/invalid"] == 3
    json.dumps(report, allow_nan=False)  # the report is strict JSON


def test_100k_status_documents_keep_the_auditor_bounded_with_the_same_figures(auditor: TruthAuditor) -> None:
    """Every status' delay figure is summarised, not kept: the items held stay within the histogram's buckets."""
    marker = 0.123456789
    template = ex.gateway_status(START_NS, ur5=ex.robot_status(t_delay_s=marker)).model_dump_json()
    assert template.count(repr(marker)) == 1
    delays_s = [0.05 + (k * 7919 % 100_000) * 1e-5 for k in range(100_000)]  # 0.05 … 1.05 s, all different
    for delay_s in delays_s:
        auditor.on_status(template.replace(repr(marker), repr(delay_s)).encode())
    gateway = auditor.report(1.0)["robots"]["ur5"]["gateway"]
    assert auditor.status_received == 100_000
    assert auditor.n_items_stored() <= 100  # the histogram is a fixed array; a list held 100,000
    assert gateway["status_documents"] == 100_000
    assert gateway["t_delay_s_max"] == round(max(delays_s), 4)
    assert gateway["t_delay_s_median"] == pytest.approx(statistics.median(delays_s), abs=1e-4)


def test_every_programs_zenoh_session_maps_no_shared_memory() -> None:
    """Zenoh keeps every shared-memory pool a sender ever lent it, with its descriptors, after the sender exited
    (~18 MB and 2 descriptors per gateway restart for the auditor in the 60-minute soak): every session has it off."""
    conf = session_config([], ["tcp/127.0.0.1:7447"], SessionOptions())
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]


# -- the program ---------------------------------------------------------------------------------------


def _start_audit(tmp_path: Path, extra: list[str]) -> tuple[Program, str, Path]:
    endpoint = free_endpoint()
    log_path = tmp_path / "audit.log"
    proc = start_program("hrc_tools.audit", ["--zenoh-listen", endpoint, *extra], log_path)
    wait_or_fail(lambda: "auditing cell" in log_path.read_text(), 30.0, "the auditor's start", [log_path], [proc])
    return proc, endpoint, log_path


def _play(endpoint: str, seconds: float, human_at: tuple[float, float, float]) -> None:
    """Play controller (250 Hz truth + emu stats) and tracker truth (100 Hz) in real time."""
    with zenoh.open(session_config(connect=[endpoint])) as session:
        time.sleep(0.3)
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < seconds:
            now = time.time_ns()
            if k % 2 == 0:
                session.put(keys.truth_humans("demo"), humans(k // 2 + 1, now, human_at))
            session.put(STATE_KEY, state(k, now))
            k += 1
            time.sleep(0.004)
        session.put(keys.robot_emu_stats("demo", "ur5"), json.dumps({"cycles_completed": 3}).encode())
        time.sleep(0.2)


def test_program_exits_1_on_a_violation_with_summary_and_json(tmp_path: Path) -> None:
    json_path = tmp_path / "audit.json"
    proc, endpoint, log_path = _start_audit(tmp_path, ["--duration-s", "2.5", "--json", str(json_path)])
    try:
        _play(endpoint, 1.0, (0.45, -0.35, 1.15))
        assert proc.wait(30) == EXIT_VIOLATION, log_path.read_text()
    finally:
        stop_all([proc])
    report = json.loads(json_path.read_text())
    r = report["robots"]["ur5"]
    assert r["violations"] > 100
    assert r["program_cycles_completed"] == 3
    assert report["human_truth_received"] > 50
    out = log_path.read_text()
    assert "VIOLATION" in out
    assert "smallest margin" in out
    assert "first violation" in out


def test_program_until_sigterm_passes_a_safe_run(tmp_path: Path) -> None:
    json_path = tmp_path / "audit.json"
    proc, endpoint, log_path = _start_audit(tmp_path, ["--json", str(json_path)])
    try:
        _play(endpoint, 0.8, (4.0, 0.0, 1.0))
        assert stop_program(proc, signal.SIGTERM) == EXIT_OK, log_path.read_text()
    finally:
        stop_all([proc])
    report = json.loads(json_path.read_text())
    assert report["verdict"] == "pass"
    assert report["robots"]["ur5"]["cycles"] > 100


def test_help_names_the_exit_codes_and_bad_options_exit_2() -> None:
    help_text = subprocess.run(
        [sys.executable, "-m", "hrc_tools.audit", "--help"], capture_output=True, text=True, timeout=60, cwd=REPO_ROOT
    ).stdout
    assert "1 at least one violation" in " ".join(help_text.split())
    result = subprocess.run(
        [sys.executable, "-m", "hrc_tools.audit", "--duration-s", "-1"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1


def test_nothing_to_audit_is_inconclusive(tmp_path: Path) -> None:
    proc, _, log_path = _start_audit(tmp_path, ["--duration-s", "0.3"])
    assert proc.wait(30) == EXIT_INCONCLUSIVE, log_path.read_text()
    assert "INCONCLUSIVE" in log_path.read_text()


def test_truth_from_a_stepped_clock_is_refused_not_paired_with_the_robot_seconds_later(auditor: TruthAuditor) -> None:
    """The soak's clock step on the tracker's host: truth captured while a person touched the tool, stamped 4 s
    ahead, must not be paired with the robot's states 4 s later (the person had left; the robot ran again)."""
    step_ns = 4_000_000_000
    for k in range(10):  # the person at the tool, the truth publisher's clock 4 s ahead
        stamp = START_NS + k * CYCLE_NS
        auditor.on_truth_humans(humans(k + 1, stamp + step_ns, (0.45, -0.35, 1.15)), received_wall_ns=stamp)
    for k in range(10):  # 4 s later: the robot moving, the (stale) truth's stamps would match these states
        stamp = START_NS + step_ns + k * CYCLE_NS
        auditor.on_truth_state(STATE_KEY, state(k, stamp), received_wall_ns=stamp)
    auditor.process()
    report = auditor.report(5.0)
    assert report["rejected"].get("truth_humans/clock_off") == 10
    r = report["robots"]["ur5"]
    assert r["violations"] == 0
    assert r["cycles"] == 0  # nothing judged: no truth of people at that time


def test_truth_on_time_is_judged_as_before(auditor: TruthAuditor) -> None:
    for k in range(10):
        stamp = START_NS + k * CYCLE_NS
        auditor.on_truth_humans(humans(k + 1, stamp, (0.45, -0.35, 1.15)), received_wall_ns=stamp + 3_000_000)
        auditor.on_truth_state(STATE_KEY, state(k, stamp), received_wall_ns=stamp + 2_000_000)
    auditor.process()
    assert auditor.report(1.0)["robots"]["ur5"]["violations"] == 10


def _as_open(cell_config: CellConfig) -> CellConfig:
    robot = cell_config.robots["ur5"]
    controller = robot.controller.model_copy(update={"control": "open"})
    return cell_config.model_copy(update={"robots": {"ur5": robot.model_copy(update={"controller": controller})}})


def test_an_open_robot_is_judged_by_its_speed_fraction_not_its_override(
    cell_config: CellConfig, ur5: RobotModel
) -> None:
    """An open controller reports override 1.0 whatever its speed; its stop lasts max_j |q̇_j| / q̇max_j of its
    stop time, and the auditor judges that stop: a slow open robot near a person passes where the same state
    read as a closed one at δ = 1 (a full stop ahead) fails, and a fast one fails as the closed one does."""
    near = (0.45, -0.35, 1.45)  # a hand 0.3 m above the touching one: ~0.2 m from the tool
    slow = [0.05 * v for v in QD]  # 1.6 % of the base's limit (3.15 rad/s): a 4 ms stop

    def run(config: CellConfig, qd: list[float]) -> dict[str, object]:
        auditor = TruthAuditor(config, {"ur5": ur5}, START_NS)
        for k in range(10):
            stamp = START_NS + k * CYCLE_NS
            auditor.on_truth_humans(humans(k + 1, stamp, near))
            message = JointState(
                robot="ur5",
                seq=k,
                stamp_ns=stamp,
                q=Q_PICK_ABOVE,
                qd=qd,
                qd_nominal=qd,
                override=1.0,
                override_seq=k,
                mode="running",
            )
            auditor.on_truth_state(STATE_KEY, to_payload(message))
        auditor.process()
        return auditor.report(1.0)["robots"]["ur5"]

    assert run(cell_config, slow)["violations"] == 10  # closed at δ = 1: a 0.24 s stop with K = 1.6 m/s
    open_slow = run(_as_open(cell_config), slow)
    assert open_slow["violations"] == 0
    assert open_slow["smallest_margin_m"] > 0.0
    fast = [v * 3.0 for v in QD]  # the base at 95 % of its limit: nearly the whole stop ahead
    assert run(_as_open(cell_config), fast)["violations"] == 10
