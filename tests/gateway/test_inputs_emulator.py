"""The input checks against the real controller emulator: the joint states it reports while its applied override
ramps up and down (acceleration and braking, through moves and dwells) are consistent (qd = override ·
qd_nominal, sign included), continuous (no q_jump) and echo overrides after they were sent; nothing is rejected.

A closed loop at the InputStore level, no network: the gateway's overrides reach the ControllerNode after a fixed
latency, its joint states reach the store after a fixed transit, on one shared simulated clock.
"""

from __future__ import annotations

import numpy as np
import pytest

from controller_emu.node import ControllerNode
from gateway.inputs import InputStore
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import Override, to_payload
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks

EPOCH_NS = 1_790_000_000_000_000_000
MS = 1_000_000
OVERRIDE_LATENCY_NS = 3 * MS
STATE_TRANSIT_NS = 1 * MS
GATEWAY_OFFSET_NS = 2 * MS  # the gateway decides 2 ms after each controller cycle
HOLD_MS = 300  # each commanded δ is held this long: full ramps up (0.5 s) and down (0.24 s) both happen


def _at(t_ns: int) -> Clocks:
    """Simulated time ``t_ns`` on both clocks of every process (wall from the epoch, monotonic from 0)."""
    return Clocks(EPOCH_NS + t_ns, t_ns)


def _commanded(rng: np.random.Generator, n: int) -> list[float]:
    """A seeded schedule of commanded overrides: stops, full speed and values between."""
    choices = [0.0, 1.0, 0.3, 1.0, 0.0, float(rng.uniform(0, 1)), 0.6, 0.05]
    return [choices[int(rng.integers(len(choices)))] for _ in range(n)]


@pytest.mark.parametrize("seed", [3, 17])
def test_the_emulator_passes_every_input_check_through_its_ramps(
    cell_config: CellConfig, ur5: RobotModel, seed: int
) -> None:
    robot = cell_config.robots["ur5"]
    trajectory = load_trajectory(robot.program, ur5)
    rng = np.random.default_rng(seed)
    node = ControllerNode("ur5", trajectory, robot.controller, tau0_s=float(rng.uniform(0, trajectory.duration_s)))
    store = InputStore(cell_config, {"ur5": ur5})
    key = keys.robot_state(cell_config.cell, "ur5")
    cycle_ns = round(robot.controller.cycle_s * 1e9)
    schedule = _commanded(rng, 40)
    overrides: list[tuple[int, bytes]] = []  # (arrival at the controller, payload)
    states: list[tuple[int, bytes]] = []  # (arrival at the gateway, payload)
    applied: list[float] = []
    for k in range(len(schedule) * HOLD_MS * MS // cycle_ns):
        t_ns = k * cycle_ns
        while overrides and overrides[0][0] <= t_ns:
            arrival_ns, payload = overrides.pop(0)
            assert node.on_override(payload, _at(arrival_ns)) is None
        output = node.cycle(_at(t_ns))
        applied.append(output.state.delta_applied)
        states.append((t_ns + STATE_TRANSIT_NS, to_payload(output.joint_state)))
        decide_ns = t_ns + GATEWAY_OFFSET_NS
        while states and states[0][0] <= decide_ns:
            arrival_ns, payload = states.pop(0)
            store.on_joint_state(key, payload, _at(arrival_ns))
        snap = store.snapshot(_at(decide_ns))
        assert snap.faults == {}, (k, snap.faults)
        seq = k + 1
        delta = schedule[int(decide_ns // (HOLD_MS * MS))]
        store.on_override_sent("ur5", seq, delta, _at(decide_ns))
        message = Override(robot="ur5", seq=seq, stamp_ns=EPOCH_NS + decide_ns, delta=delta)
        overrides.append((decide_ns + OVERRIDE_LATENCY_NS, to_payload(message)))
    assert store.counters()[0] == {}
    path = store.snapshot(_at(decide_ns)).override_path["ur5"]
    assert path.latency_s is not None
    # the loop really ramped: δ took values strictly between 0 and 1, rising and falling
    ramp = np.diff(applied)
    assert (ramp > 0).sum() > 100
    assert (ramp < 0).sum() > 50
