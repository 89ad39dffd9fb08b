"""How much of the joint-motion tolerance honest controllers use (``gateway.joint_motion``).

    .venv/bin/python -m bench.joint_motion [--seeds 3] [--duration-s 9]

Runs honest joint-state streams through the gateway's door and prints, per source, the largest share of its
tolerance any judged state used (``tolerance_used``: 1.0 would be a ``q_motion_inconsistent`` fault), with the
states judged and the faults seen:

- ``emulator``: the controller emulator in a closed loop with the door, 4 ms cycles, overrides ramping through stops
  and full speed; ``emulator_late``: the same with 10 % of cycles late by up to 40 ms and each stamp read up to
  0.5 ms after the cycle's monotonic time (what a loaded host does to the emulator: its stamps are the cycle's wall
  clock, its motion the monotonic time since the previous cycle);
- ``sim_<interface>``: the simulated cell's walk-in scenario (``tests/hrc_tools/sim/test_bridged.py``) through the
  Zenoh face, the UR bridge at 500 and 125 Hz, and the ABB bridge (q differenced over the poll).
"""

from __future__ import annotations

import argparse
import math
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from controller_emu.node import ControllerNode
from gateway import joint_motion
from gateway.inputs import InputStore
from hrc_contract import keys
from hrc_contract.config import CellConfig, TrackerConfig
from hrc_contract.messages import Override, to_payload
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.bridged import default_interface
from hrc_tools.sim.cell import simulate
from hrc_tools.sim.links import LinkFaults
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

EPOCH_NS = 1_790_000_000_000_000_000
MS = 1_000_000


@contextmanager
def _measured() -> Iterator[list[float]]:
    """Record ``tolerance_used`` of every state the door judges while the block runs."""
    used: list[float] = []
    original: Callable[..., Any] = joint_motion.contradiction

    def recording(history: deque[joint_motion.MotionEntry], state: joint_motion.MotionEntry) -> Any:
        used.append(joint_motion.tolerance_used(history, state))
        return original(history, state)

    joint_motion.contradiction = recording
    try:
        yield used
    finally:
        joint_motion.contradiction = original


def _emulator(config: CellConfig, ur5: RobotModel, seed: int, late: bool, duration_s: float) -> tuple[int, int]:
    """The emulator in a closed loop with the door; (faults seen, rejections)."""
    robot = config.robots["ur5"]
    trajectory = load_trajectory(robot.program, ur5)
    rng = np.random.default_rng(seed)
    node = ControllerNode("ur5", trajectory, robot.controller, tau0_s=float(rng.uniform(0, trajectory.duration_s)))
    store = InputStore(config, {"ur5": ur5})
    key = keys.robot_state(config.cell, "ur5")
    choices = [0.0, 1.0, 0.3, 1.0, 0.0, 0.6, 0.05]
    t_ns, seq, faults = 0, 0, 0
    while t_ns < duration_s * 1e9:
        t_ns += 4 * MS + (int(rng.uniform(0, 40 * MS)) if late and rng.random() < 0.1 else 0)
        stamp_lag_ns = int(rng.uniform(0, 0.5 * MS)) if late else 0
        seq += 1
        delta = choices[(t_ns // (300 * MS)) % len(choices)]
        store.on_override_sent("ur5", seq, delta, Clocks(EPOCH_NS + t_ns - 3 * MS, t_ns - 3 * MS))
        node.on_override(
            to_payload(Override(robot="ur5", seq=seq, stamp_ns=EPOCH_NS + t_ns - 3 * MS, delta=delta)),
            Clocks(EPOCH_NS + t_ns - 1 * MS, t_ns - 1 * MS),
        )
        output = node.cycle(Clocks(EPOCH_NS + t_ns + stamp_lag_ns, t_ns))
        arrival = Clocks(EPOCH_NS + t_ns + stamp_lag_ns + MS, t_ns + stamp_lag_ns + MS)
        store.on_joint_state(key, to_payload(output.joint_state), arrival)
        faults += bool(store.snapshot(arrival).faults)
    return faults, sum(sum(r.values()) for r in store.counters()[0].values())


WALK_S = 9.0


def _walk(duration_s: float) -> Scenario:
    return Scenario(
        description="one person walks up to the robot, stands, and walks away",
        duration_s=duration_s,
        loop=False,
        humans=[
            HumanScript(
                id="h1",
                keyframes=[
                    Keyframe(t_s=0.0, xy_m=(4.5, 0.3), heading_rad=math.pi),
                    Keyframe(t_s=duration_s / 6, xy_m=(4.5, 0.3), heading_rad=math.pi),
                    Keyframe(t_s=duration_s * 7 / 18, xy_m=(1.1, 0.3), heading_rad=math.pi),
                    Keyframe(t_s=duration_s / 2, xy_m=(1.1, 0.3), heading_rad=math.pi),
                    Keyframe(t_s=duration_s * 13 / 18, xy_m=(4.5, 0.3), heading_rad=0.0),
                    Keyframe(t_s=duration_s, xy_m=(4.5, 0.3), heading_rad=0.0),
                ],
            )
        ],
    )


def _sim(
    config: CellConfig, ur5: RobotModel, interface: str, fields: dict[str, Any], seed: int, duration_s: float
) -> str:
    """The simulated walk-in through ``interface``; the robot's input rejections by reason."""
    raw = config.model_dump()
    raw["trackers"] = {
        "front": TrackerConfig(rate_hz=30.0, noise_std_m=0.01, drop_probability=0.0, latency_s=0.03).model_dump()
    }
    for robot in raw["robots"].values():
        robot["interface"] = default_interface(interface) | fields
    result = simulate(CellConfig.model_validate(raw), {"ur5": ur5}, _walk(duration_s), LinkFaults(), duration_s, seed)
    return f"rejected {dict(result.rejected.get('robot/ur5', {}))}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.joint_motion", description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--duration-s", type=float, default=WALK_S, help="per seed and source; at least 6 s [s]")
    args = parser.parse_args(argv)
    config = load_cell_config(None)
    ur5 = load_robot_model("ur5", config.robots["ur5"])
    print(f"{'source':<22} {'states':>8} {'max used':>9} {'p99.9 used':>10}  notes")

    def emulator(late: bool) -> Callable[[int], str]:
        def run(seed: int) -> str:
            faults, rejections = _emulator(config, ur5, seed, late, args.duration_s)
            return f"faults {faults}, rejections {rejections}"

        return run

    def bridged(interface: str, fields: dict[str, Any]) -> Callable[[int], str]:
        return lambda seed: _sim(config, ur5, interface, fields, seed, args.duration_s)

    cases: list[tuple[str, Callable[[int], str]]] = [
        ("emulator", emulator(False)),
        ("emulator_late", emulator(True)),
        ("sim_zenoh", bridged("zenoh", {})),
        ("sim_ur_rtde_500hz", bridged("ur_rtde", {"frequency_hz": 500})),
        ("sim_ur_rtde_125hz", bridged("ur_rtde", {"frequency_hz": 125})),
        ("sim_abb_rws", bridged("abb_rws", {})),
    ]
    for name, run in cases:
        with _measured() as used:
            notes = [run(seed) for seed in range(args.seeds)]
        figures = np.asarray(used) if used else np.zeros(1)
        print(
            f"{name:<22} {len(used):>8} {figures.max():>9.3f} {np.quantile(figures, 0.999):>10.3f}  "
            f"{'; '.join(sorted(set(notes)))}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
