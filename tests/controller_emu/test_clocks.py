"""The controller's two clocks under hostile conditions: wall-clock steps and stamps from the future.

The watchdog runs on the controller's monotonic clock; the gateway's stamps are compared only with the
controller's wall clock (stale if older than the watchdog, rejected if more than MAX_FUTURE_STAMP_S ahead).
Each test drives a :class:`ControllerNode` on hand-stepped clocks: the gateway sends an override half a
cycle before each controller cycle, stamped with its own wall clock.
"""

from __future__ import annotations

import pytest

from controller_emu.node import ControllerNode, ControllerOutput
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_contract.messages import Override, to_payload
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_devices.robots.time_scaling import MAX_FUTURE_STAMP_S
from hrc_runtime.clocks import Clocks

ROBOT = "ur5"
T0_NS = 1_790_000_000_000_000_000
MS_NS = 1_000_000
JUMP_NS = 10_000_000_000
"""A wall-clock step of 10 s (an NTP step, a manual `date -s`)."""


class Cell:
    """The controller's monotonic and wall clocks, the gateway's wall clock, and the node they drive."""

    def __init__(self, node: ControllerNode) -> None:
        self.node = node
        self.cycle_ns = round(node.config.cycle_s * 1e9)
        self.mono_ns = 0
        self.wall_ns = T0_NS
        self.gateway_wall_ns = T0_NS
        self.seq = 0

    def now(self) -> Clocks:
        """The controller's clocks now."""
        return Clocks(wall_ns=self.wall_ns, mono_ns=self.mono_ns)

    def advance(self, dt_ns: int) -> None:
        """Real time passes: every clock advances by ``dt_ns``."""
        self.mono_ns += dt_ns
        self.wall_ns += dt_ns
        self.gateway_wall_ns += dt_ns

    def send(self, delta: float, stamp_offset_ns: int = 0) -> str | None:
        """An override arrives now, stamped with the gateway's wall clock (plus ``stamp_offset_ns``)."""
        message = Override(robot=ROBOT, seq=self.seq, stamp_ns=self.gateway_wall_ns + stamp_offset_ns, delta=delta)
        self.seq += 1
        return self.node.on_override(to_payload(message), self.now())

    def cycle(self, delta: float | None, jump_mid_cycle_ns: int = 0) -> tuple[ControllerOutput, str | None]:
        """Half a cycle, the gateway's override (unless None), the controller wall clock stepped by
        ``jump_mid_cycle_ns``, half a cycle, the controller's cycle. Returns its output and the override's fate."""
        self.advance(self.cycle_ns // 2)
        reason = None if delta is None else self.send(delta)
        self.wall_ns += jump_mid_cycle_ns
        self.advance(self.cycle_ns - self.cycle_ns // 2)
        return self.node.cycle(self.now()), reason


@pytest.fixture
def config(cell_config: CellConfig) -> ControllerConfig:
    return cell_config.robots[ROBOT].controller


@pytest.fixture
def clocks(cell_config: CellConfig, ur5: RobotModel, config: ControllerConfig) -> Cell:
    trajectory = load_trajectory(cell_config.robots[ROBOT].program, ur5)
    clocks = Cell(ControllerNode(ROBOT, trajectory, config))
    for _ in range(round(config.accel_time_s / config.cycle_s) + 2):
        clocks.cycle(1.0)
    assert clocks.node.state.delta_applied == 1.0
    return clocks


def _stop_after_last_accepted(clocks: Cell, delta: float | None, cycles: int) -> tuple[float, list[str | None]]:
    """Cycle with ``delta`` sent every cycle; the monotonic time from the last accepted override to the first
    protective-stop cycle [s], and the fate of every override sent."""
    accepted_mono_ns = clocks.node.state.override_accepted_mono_ns
    assert accepted_mono_ns is not None
    reasons = []
    for _ in range(cycles):
        output, reason = clocks.cycle(delta)
        reasons.append(reason)
        if output.state.mode == "protective_stop":
            return (clocks.mono_ns - accepted_mono_ns) / 1e9, reasons
        assert output.state.mode == "running"
        assert output.state.delta_applied == 1.0, "the last valid override holds until the watchdog expires"
    raise AssertionError(f"no protective stop within {cycles} cycles")


# --- (1) the controller's wall clock steps back --------------------------------------------------------


@pytest.mark.parametrize(
    ("gateway_steps_too", "reason"),
    [(False, "stamp_in_future"), (True, "old_or_repeated")],
    ids=["controller-clock-only", "same-host-both-clocks"],
)
def test_wall_clock_step_back_does_not_extend_the_watchdog(
    clocks: Cell, config: ControllerConfig, gateway_steps_too: bool, reason: str
) -> None:
    """Right after an accepted override the wall clock steps back 10 s. The overrides that follow are 10 s
    ahead of the controller's clock (rejected: from the future) or, if the gateway's clock stepped too,
    10 s behind the last accepted stamp (rejected: old). Either way the robot stops ``watchdog_s`` after
    the last accepted override, on the monotonic clock; a wall-clock watchdog would run on for 10 s."""
    _, accepted = clocks.cycle(1.0)
    assert accepted is None
    clocks.wall_ns -= JUMP_NS
    if gateway_steps_too:
        clocks.gateway_wall_ns -= JUMP_NS
    silent_s, reasons = _stop_after_last_accepted(clocks, 1.0, 100)
    assert config.watchdog_s < silent_s <= config.watchdog_s + config.cycle_s
    assert set(reasons) == {reason}
    assert clocks.node.stats().rejected[reason] == len(reasons)


def test_wall_clock_step_back_without_overrides_still_expires(clocks: Cell, config: ControllerConfig) -> None:
    clocks.cycle(1.0)
    clocks.wall_ns -= JUMP_NS
    silent_s, _ = _stop_after_last_accepted(clocks, None, 100)
    assert config.watchdog_s < silent_s <= config.watchdog_s + config.cycle_s


# --- (2) the controller's wall clock steps forward -----------------------------------------------------


def test_controller_clock_step_forward_fails_closed_after_the_watchdog(clocks: Cell, config: ControllerConfig) -> None:
    """Only the controller's wall clock steps forward 10 s: every override now looks 10 s old, so it is
    stale and the robot stops. Not at once (that would be a wall-clock watchdog seeing 10 s of silence):
    the last valid override holds for ``watchdog_s`` on the monotonic clock, then the protective stop."""
    output, reason = clocks.cycle(1.0, jump_mid_cycle_ns=JUMP_NS)
    assert (output.state.mode, reason) == ("running", None)
    silent_s, reasons = _stop_after_last_accepted(clocks, 1.0, 100)
    assert config.watchdog_s < silent_s <= config.watchdog_s + config.cycle_s
    assert set(reasons) == {"stale"}
    # And it stays stopped while the clocks disagree: fail closed, never a stale command.
    for _ in range(100):
        output, reason = clocks.cycle(1.0)
        assert (output.state.mode, reason) == ("protective_stop", "stale")
    assert output.state.delta_applied == 0.0


def test_same_host_clock_step_forward_does_not_stop_the_robot(clocks: Cell) -> None:
    """Both wall clocks step forward 10 s between an override's arrival and the controller's cycle (same
    host): the overrides that follow are fresh and newer, so the robot keeps running at δ = 1 without a
    single protective-stop cycle (a wall-clock watchdog would see 10 s of silence at the next cycle)."""
    output, reason = clocks.cycle(1.0, jump_mid_cycle_ns=JUMP_NS)
    clocks.gateway_wall_ns += JUMP_NS
    outputs = [output] + [clocks.cycle(1.0)[0] for _ in range(100)]
    assert reason is None
    assert all(o.state.mode == "running" and o.state.delta_applied == 1.0 for o in outputs)
    assert all(o.mode_change is None for o in outputs)
    assert not clocks.node.stats().rejected


# --- (3) stamps from the future ------------------------------------------------------------------------


def test_a_stamp_1_ms_ahead_is_accepted_10_ms_ahead_is_rejected(clocks: Cell) -> None:
    assert clocks.send(0.5, stamp_offset_ns=10 * MS_NS) == "stamp_in_future"
    assert clocks.send(0.5, stamp_offset_ns=1 * MS_NS) is None
    assert clocks.node.cycle(clocks.now()).state.delta_commanded == 0.5
    assert dict(clocks.node.stats().rejected) == {"stamp_in_future": 1}


def test_a_forged_far_future_override_does_not_mask_a_genuine_stop(clocks: Cell) -> None:
    """A forged δ = 1 stamped 10 ms ahead would, if accepted, make every genuine override stamped before it
    look old. It is rejected, so the genuine δ = 0 right after it is obeyed."""
    assert clocks.send(1.0, stamp_offset_ns=10 * MS_NS) == "stamp_in_future"
    output, reason = clocks.cycle(0.0)
    assert reason is None
    assert output.state.delta_commanded == 0.0
    assert output.state.delta_applied < 1.0, "braking has begun"


@pytest.mark.parametrize("forged_ahead_ms", [0.5, 1.0, 2.0, 4.0, 4.9, 5.0])
def test_a_forged_override_within_the_limit_masks_genuine_ones_for_at_most_the_limit(
    clocks: Cell, forged_ahead_ms: float
) -> None:
    """A forged δ = 1 stamped up to MAX_FUTURE_STAMP_S ahead is accepted; the genuine δ = 0 overrides
    (every 1 ms here, stamped on arrival) stamped before it are rejected as old, but the first stamped
    after it is accepted: the forged message holds the stop back by at most MAX_FUTURE_STAMP_S."""
    forged_at_ns = clocks.mono_ns
    assert clocks.send(1.0, stamp_offset_ns=round(forged_ahead_ms * MS_NS)) is None
    reasons = []
    while True:
        clocks.advance(MS_NS)
        reason = clocks.send(0.0)
        if reason is None:
            break
        reasons.append(reason)
    masked_s = (clocks.mono_ns - forged_at_ns) / 1e9
    assert set(reasons) <= {"old_or_repeated"}
    assert masked_s <= MAX_FUTURE_STAMP_S + 0.001  # the first genuine stamp after the forged one
    assert masked_s > forged_ahead_ms * 1e-3
    assert clocks.node.cycle(clocks.now()).state.delta_commanded == 0.0


def test_forged_4_ms_ahead_then_genuine_1_ms_later_and_the_next_one(clocks: Cell) -> None:
    """The case of the brief, at the gateway's 4 ms period: the genuine override 1 ms after a forged one
    stamped +4 ms is older (rejected), the next genuine one 4 ms later is newer (accepted)."""
    assert clocks.send(1.0, stamp_offset_ns=4 * MS_NS) is None
    clocks.advance(1 * MS_NS)
    assert clocks.send(0.0) == "old_or_repeated"
    clocks.advance(4 * MS_NS)
    assert clocks.send(0.0) is None
    assert clocks.node.cycle(clocks.now()).state.delta_commanded == 0.0
