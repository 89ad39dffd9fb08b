"""One open robot's task and reference between cycles: the program as a task, the CLIK, the LPs' inputs.

The gateway runs an open robot's program itself (paper 1, Sec. III): the task is the tool's pose along the program,
x(τ) = k(q_p(τ)), x'(τ) = J_tool(q_p(τ)) q̇_p(τ); τ advances by δ each cycle; the reference q_ref integrates the
commanded q̇. The safety rows are built at the *measured* joints (what the robot is), the task and the joint limits
at the reference (what it is told). :meth:`gateway.open_kernels.OpenLp.decide` (the compiled
:func:`gateway.open_control.decide`) chooses the command.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from gateway import open_control
from gateway.kinematics import LinkKinematics
from gateway.open_control import Limits, SafetyRows, Solution, Task
from gateway.open_kernels import OpenLp
from gateway.plan import Plan, Sampler
from gateway.separation import ConstraintRows
from hrc_contract.config import ConfigError
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import Trajectory

FloatArray = npt.NDArray[np.float64]

CLIK_GAIN_PER_S = 10.0
"""K of (9c): the reference's pose error decays with this rate [1/s] (paper 1's CLIK; 10/s corrects in ~0.3 s)."""
CLIK_MAX_MPS = 0.25
"""The CLIK term's linear part is clipped to this [m/s] (a robot far from its path comes back slowly, not in a jump)."""
CLIK_MAX_RADPS = 0.5
"""… and its angular part to this [rad/s]."""
POSTURE_GAIN_PER_S = 2.0
"""q̇⁰ pulls the redundant joints back to the program's posture at this rate [1/s] when nobody is near."""
AWAY_GAIN_RADPS = 1.0
"""q̇⁰'s push away from people at full weight: the largest joint speed of that push [rad/s]."""
AWAY_INFLUENCE_M = 2.0
"""People nearer than this to a link (surface distance) push it away; the weight grows linearly to 1 at contact [m]."""
RESYNC_RAD = 0.05
"""A reference this far from the measured joints (the robot did not follow: a protective stop, a restart) starts
again from the measured state [rad]: far from every reference sent within the measured round trip (a measured state
shows where the robot was one round trip ago, so on a slow link it trails the newest reference by q̇ × that time)."""
SENT_KEPT = 256
"""References kept for that comparison: 1 s of commands at 250 Hz; a round trip longer than what they cover is
compared with the oldest kept."""


class OpenCommand(NamedTuple):
    """What the gateway sends an open robot this cycle, and why.

    Attributes:
        q_rad: the reference position for the next cycle, every joint of the model [rad].
        qd_radps: the reference velocity, every joint [rad/s].
        solution: the LPs' answer (active joints only) and how it was reached.
        rows: the safety rows it kept (for the status: how many bound it).
    """

    q_rad: FloatArray
    qd_radps: FloatArray
    solution: Solution
    rows: int
    rows_dropped: int
    reference_restarts: int = 0
    """Times the reference started again from the measured state because the robot did not follow (since start)."""
    program_cycles: float = 0.0
    """The program time made good (:meth:`OpenRobot.progress_tau_s`), in cycles of the program."""


def active_joints(robot: RobotModel, tool_frame_id: int) -> npt.NDArray[np.intp]:
    """The joints that move the tool or a link capsule (the rest, e.g. a gripper's fingers, are held still): the
    ancestors of the tool's frame and of every link-end frame, as velocity indices."""
    model = robot.model
    joints: set[int] = set()
    for frame_id in (tool_frame_id, *robot.frame_a_ids, *robot.frame_b_ids):
        j = int(model.frames[frame_id].parentJoint)
        while j > 0:
            joints.add(j)
            j = int(model.parents[j])
    return np.array(sorted(int(model.joints[j].idx_v) for j in joints), dtype=np.intp)


def pose_error(target: pin.SE3, current: pin.SE3) -> FloatArray:
    """ε of (9c) in the world-aligned frame: position difference and the rotation vector from current to target."""
    rotation = np.asarray(target.rotation @ current.rotation.T, dtype=float)
    return np.concatenate(
        (np.asarray(target.translation - current.translation, dtype=float), np.asarray(pin.log3(rotation), dtype=float))
    )


def clipped_correction(error: FloatArray) -> FloatArray:
    """K ε with its linear and angular parts clipped to :data:`CLIK_MAX_MPS` and :data:`CLIK_MAX_RADPS`."""
    out = CLIK_GAIN_PER_S * error
    for part, limit in ((slice(0, 3), CLIK_MAX_MPS), (slice(3, 6), CLIK_MAX_RADPS)):
        norm = float(np.linalg.norm(out[part]))
        if norm > limit:
            out[part] *= limit / norm
    return out


def nearest_people(
    links: LinkKinematics, humans: HumanCapsules, surface_distance_m: FloatArray | None
) -> tuple[FloatArray | None, FloatArray | None]:
    """Per link, the nearest capsule's point nearest to the link's middle and the link's surface distance to it (from
    eq. (15)'s distances, shape (L, H)); (None, None) with nobody or without distances. For the self-motion only:
    the safety rows never use it."""
    if surface_distance_m is None or not humans.n_capsules or not surface_distance_m.size:
        return None, None
    nearest = np.argmin(np.where(np.isfinite(surface_distance_m), surface_distance_m, np.inf), axis=1)
    distance = surface_distance_m[np.arange(len(nearest)), nearest]
    a, b = humans.h_a_world[nearest], humans.h_b_world[nearest]
    middle = 0.5 * (links.p_a_world + links.p_b_world)
    axis = b - a
    length2 = (axis * axis).sum(axis=1)
    t = np.clip(((middle - a) * axis).sum(axis=1) / np.where(length2 > 1e-12, length2, 1.0), 0.0, 1.0)
    return a + t[:, None] * axis, np.asarray(distance, dtype=float)


class AccelerationOverLimit(NamedTuple):
    """A move of the program whose joint accelerates faster than the open controller's q̈max allows (LP (9d))."""

    waypoint: int
    """The waypoint the move goes into."""
    joint: str
    accel_radps2: float
    """That joint's acceleration in the move at δ = 1 [rad/s²]."""
    limit_radps2: float
    """Its q̈max = q̇max / ``controller.braking_time_s`` [rad/s²]."""


def accelerations_over_limit(
    trajectory: Trajectory, joint_names: Sequence[str], active: npt.NDArray[np.intp], qdd_max_radps2: FloatArray
) -> list[AccelerationOverLimit]:
    """Per move of the program, its joint (of ``active``, limits ``qdd_max_radps2`` in that order) that accelerates
    most above its q̈max, if any: such a move cannot be followed at δ = 1 (window (9d) of LP (9)), so δ drops in it
    with nobody near. Productivity, not safety: the rows hold whatever δ is."""
    out = []
    for segment in trajectory.segments:
        if segment.distance_rad == 0.0:
            continue
        accel = segment.accel_radps2 * np.abs(segment.direction[active])
        over = accel - qdd_max_radps2 * (1.0 + 1e-9)
        j = int(np.argmax(over))
        if over[j] > 0.0:
            out.append(
                AccelerationOverLimit(
                    segment.waypoint, joint_names[int(active[j])], float(accel[j]), float(qdd_max_radps2[j])
                )
            )
    return out


def acceleration_warning(robot: str, over: Sequence[AccelerationOverLimit]) -> str | None:
    """One line for the operator when a program accelerates faster than its open controller's q̈max, else None."""
    if not over:
        return None
    worst = max(over, key=lambda o: o.accel_radps2 / o.limit_radps2)
    waypoints = ", ".join(str(o.waypoint) for o in over)
    return (
        f"robot {robot!r}: {len(over)} move(s) of its program (into waypoint(s) {waypoints}) accelerate faster than "
        f"the open controller's q̈max = q̇max / controller.braking_time_s, e.g. {worst.joint} at "
        f"{worst.accel_radps2:.2f} rad/s² against {worst.limit_radps2:.2f} rad/s² (into waypoint {worst.waypoint}): "
        "LP (9) cannot follow those moves at δ = 1, so δ drops there with nobody near (safety is unaffected); "
        "lower those waypoints' max_accel_radps2 to keep full speed"
    )


@dataclass
class OpenRobot:
    """An open robot's program time, reference and the LPs' fixed inputs."""

    robot: RobotModel
    trajectory: Trajectory
    period_s: float
    stop_time_s: float
    """The controller's stop from full speed (``controller.braking_time_s``, at most every link's t_b,→i: checked at
    start-up as for a closed controller): each joint's acceleration bound is q̇max / this, and the ramp stop lasts at
    most this [s]."""
    data: pin.Data = field(init=False)
    tool_frame_id: int = field(init=False)
    active: npt.NDArray[np.intp] = field(init=False)
    limits: Limits = field(init=False)
    lp: OpenLp = field(init=False, repr=False, compare=False)
    """LP (9) and (13)'s buffers, kept between cycles."""
    tau_s: float = 0.0
    q_ref_rad: FloatArray | None = None
    qd_prev_radps: FloatArray | None = None
    """q̇ of the previous command, every joint [rad/s]."""
    delta_prev: float = 0.0
    last_mono_ns: int | None = None
    plan: Plan | None = None
    """A plan around people the robot follows instead of the program (the planner layer), None on the program."""
    plan_t_s: float = 0.0
    """The task's time on :attr:`plan` [s]."""
    plan_from_tau_s: float = 0.0
    """The program time at which the robot left the program for the current plan [s]."""
    plans_adopted: int = 0
    plans_finished: int = 0
    sent_q_rad: FloatArray = field(init=False, repr=False, compare=False)
    """The active joints of the last :data:`SENT_KEPT` references sent, a ring [rad]."""
    sent_mono_ns: npt.NDArray[np.int64] = field(init=False, repr=False, compare=False)
    """When each was sent [ns, monotonic]; -1: empty."""
    sent_next: int = 0
    reference_restarts: int = 0
    """Times the reference started again from the measured joints after the first (the robot did not follow)."""
    accelerations_over_limit: list[AccelerationOverLimit] = field(init=False, repr=False, compare=False)
    """The program's moves that accelerate faster than :attr:`limits` allow (:func:`accelerations_over_limit`)."""

    def __post_init__(self) -> None:
        robot = self.robot
        moving = robot.t_brake_link_s[robot.t_brake_link_s > 0.0]
        if moving.size and not self.stop_time_s <= float(moving.min()):
            raise ConfigError(
                f"robot {robot.name!r}: controller.braking_time_s = {self.stop_time_s} s is longer than the shortest "
                f"t_b,→i of its links ({float(moving.min())} s), which the rows assume; allowed: <= it (an open "
                "controller's ramp stop must end within every link's braking time)"
            )
        self.data = robot.model.createData()
        self.tool_frame_id = robot.frame_b_ids[-1]
        self.active = active_joints(robot, self.tool_frame_id)
        qd_max = np.asarray(robot.velocity_limit_radps, dtype=float)[self.active]
        self.limits = Limits(
            qd_max,
            qd_max / self.stop_time_s,
            np.asarray(robot.model.lowerPositionLimit, dtype=float)[self.active],
            np.asarray(robot.model.upperPositionLimit, dtype=float)[self.active],
            self.stop_time_s,
        )
        self.accelerations_over_limit = accelerations_over_limit(
            self.trajectory, robot.joint_names, self.active, self.limits.qdd_max_radps2
        )
        self.lp = OpenLp()
        self.sent_q_rad = np.zeros((SENT_KEPT, self.active.size))
        self.sent_mono_ns = np.full(SENT_KEPT, -1, dtype=np.int64)

    # -- the path the task follows: the program, or a plan around people --------------------------------

    def path_now(self) -> tuple[Sampler, float, tuple[object, ...]]:
        """The trajectory the task follows, the task's time on it, and its key (what a plan must splice into)."""
        if self.plan is not None:
            return self.plan, self.plan_t_s, ("plan", id(self.plan))
        return self.trajectory, self.tau_s, ("program",)

    def reference_sample(self) -> tuple[FloatArray, FloatArray]:
        """The task's joints [rad] and nominal joint velocities [rad/s] now (at δ = 1)."""
        path, t_s, _ = self.path_now()
        return path.sample(t_s)

    def adopt(self, plan: Plan) -> bool:
        """Follow ``plan`` from where the task is now, if it starts on the trajectory the task follows at or before
        the task's time and the task has not yet passed its join: then q and q̇ of the task are continuous (the plan's
        first piece is that trajectory). Otherwise reject it (False): a late plan, or one for another trajectory.
        """
        _, t_now_s, key = self.path_now()
        if plan.start_key[:-1] != key:
            return False
        t_start_s = float(plan.start_key[-1])  # type: ignore[arg-type]
        offset_s = t_now_s - t_start_s
        prefix_s = plan.pieces[0].duration_s if len(plan.pieces) > 1 else 0.0
        if offset_s < -1e-9 or offset_s > prefix_s + 1e-9:
            return False
        self.plan_from_tau_s = self.progress_tau_s()
        self.plan = plan
        self.plan_t_s = max(offset_s, 0.0)
        self.plans_adopted += 1
        return True

    def progress_tau_s(self) -> float:
        """The program time the robot has made good: τ on the program; on a plan, τ where it left the program moved
        towards the plan's goal in proportion to the plan's time (production counted as the detour goes) [s]."""
        if self.plan is None:
            return self.tau_s
        fraction = min(self.plan_t_s / self.plan.duration_s, 1.0) if self.plan.duration_s > 0.0 else 1.0
        return self.plan_from_tau_s + fraction * (self.plan.goal_tau_s - self.plan_from_tau_s)

    def _advance(self, dt_s: float) -> None:
        """The task's time moves by ``dt_s`` (δ × elapsed); at a plan's end the program resumes at its goal."""
        if self.plan is None:
            self.tau_s += dt_s
            return
        self.plan_t_s += dt_s
        duration = self.plan.duration_s
        if self.plan_t_s >= duration:
            self.tau_s = self.plan.goal_tau_s + (self.plan_t_s - duration)
            self.plan = None
            self.plan_t_s = 0.0
            self.plans_finished += 1

    # -- kinematics ------------------------------------------------------------------------------------

    def _world(self, jacobian6: FloatArray) -> FloatArray:
        r = self.robot.R_world_base
        out = np.empty_like(jacobian6)
        out[:3] = r @ jacobian6[:3]
        out[3:] = r @ jacobian6[3:]
        return out

    def _tool(self, q_rad: FloatArray) -> tuple[pin.SE3, FloatArray]:
        """The tool's world pose and its 6 × n world-aligned Jacobian at ``q_rad``."""
        model, data = self.robot.model, self.data
        pin.computeJointJacobians(model, data, q_rad)
        pin.updateFramePlacements(model, data)
        placement = data.oMf[self.tool_frame_id]
        base = pin.SE3(self.robot.R_world_base, self.robot.p_world_base)
        jac = pin.getFrameJacobian(model, data, self.tool_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return base * placement, self._world(np.asarray(jac, dtype=float))

    def link_jacobians(self, q_rad: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Position Jacobians of every link's ends in the world frame at ``q_rad``, shape (L, 3, n_active) each."""
        model, data = self.robot.model, self.data
        pin.computeJointJacobians(model, data, q_rad)
        pin.updateFramePlacements(model, data)
        r = self.robot.R_world_base
        frames = {f: None for f in (*self.robot.frame_a_ids, *self.robot.frame_b_ids)}
        jac = {
            f: r
            @ np.asarray(pin.getFrameJacobian(model, data, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3], dtype=float)[
                :, self.active
            ]
            for f in frames
        }
        return (
            np.array([jac[f] for f in self.robot.frame_a_ids]).reshape(-1, 3, self.active.size),
            np.array([jac[f] for f in self.robot.frame_b_ids]).reshape(-1, 3, self.active.size),
        )

    def task(self, q_ref_rad: FloatArray) -> tuple[Task, FloatArray]:
        """The task equality at τ and the reference, and the program's joints at τ (for the posture pull)."""
        q_prog, qd_prog = self.reference_sample()
        target, jac_prog = self._tool(q_prog)
        x_rate = jac_prog @ qd_prog
        current, jac_ref = self._tool(q_ref_rad)
        # the CLIK term scales with δ as the path's rate does: J q̇ = δ (x' + K ε), so that q̇ = 0, δ = 0 always
        # satisfies (9c) and LP (9) always has the stop (paper 1's remark, which with δ-free K ε needs ε = 0)
        correction = clipped_correction(pose_error(target, current))
        return Task(jac_ref[:, self.active], x_rate + correction, np.zeros(6)), q_prog

    # -- the cycle -------------------------------------------------------------------------------------

    def followed(self, q_meas_rad: FloatArray, now_mono_ns: int, round_trip_s: float) -> bool:
        """True when the measured joints are within :data:`RESYNC_RAD` (every active joint) of the reference as it
        moves on now or of a reference sent within ``round_trip_s`` before now (the state measured shows where the
        robot was that long ago); False: the robot did not follow (a protective stop, a restart, another program)."""
        assert self.q_ref_rad is not None
        q = q_meas_rad[self.active]
        if float(np.max(np.abs(self.q_ref_rad[self.active] - q), initial=0.0)) <= RESYNC_RAD:
            return True
        window_ns = round(min(max(round_trip_s, 0.0), 10.0) * 1e9)
        recent = self.sent_mono_ns >= max(now_mono_ns - window_ns, 0)
        if not recent.any():
            return False
        off = np.max(np.abs(self.sent_q_rad[recent] - q), axis=1, initial=0.0)
        return bool(off.min() <= RESYNC_RAD)

    def start_from(self, q_meas_rad: FloatArray, qd_meas_radps: FloatArray) -> None:
        """The reference starts at the measured state (first cycle, or after the robot did not follow)."""
        self.q_ref_rad = np.array(q_meas_rad, dtype=float)
        qd = np.zeros_like(self.q_ref_rad)
        qd[self.active] = np.clip(qd_meas_radps[self.active], -self.limits.qd_max_radps, self.limits.qd_max_radps)
        self.qd_prev_radps = np.where(np.isfinite(qd), qd, 0.0)

    def command(
        self,
        q_meas_rad: FloatArray,
        qd_meas_radps: FloatArray,
        now_mono_ns: int,
        links: LinkKinematics,
        rows: ConstraintRows | None,
        humans: HumanCapsules,
        closest_point_m: FloatArray | None,
        link_distance_m: FloatArray | None,
        cap: Callable[[float], float],
        bound_if_infeasible: float = 0.0,
        round_trip_s: float = 0.0,
    ) -> OpenCommand:
        """This cycle's command.

        Args:
            q_meas_rad, qd_meas_radps: the measured joint state (every joint).
            now_mono_ns: the decision time [ns].
            links: the link ends at ``q_meas_rad`` (world) [m].
            rows: eq. (15)'s rows at ``q_meas_rad`` (distances, f, horizons with the measured delay); None when the
                inputs were not finite (then the ramp stop).
            humans: the capsules those rows were built against.
            closest_point_m, link_distance_m: per link, the nearest person's point and its surface distance (None
                with nobody near) [m].
            cap: the zones and faults: the most δ they allow given the LPs' δ* (:func:`gateway.open_control.decide`).
            bound_if_infeasible: eq. (15)'s bound at the program's velocity, for the zones when LP (9) has none.
            round_trip_s: from a command sent to the joint state that shows it (the measured override path, the
                controller's cycle, the joint state's age and the gateway's period) [s]: the reference starts again
                from the measured state only when that is far from every reference sent within it.
        """
        if self.q_ref_rad is None or self.qd_prev_radps is None or not np.isfinite(self.q_ref_rad).all():
            self.start_from(q_meas_rad, qd_meas_radps)
        assert self.q_ref_rad is not None
        assert self.qd_prev_radps is not None
        elapsed_s = self.period_s if self.last_mono_ns is None else max(0.0, (now_mono_ns - self.last_mono_ns) / 1e9)
        # One reference per period: a decision that comes late (the loop was held up) continues from the reference
        # sent last, which the controller has reached and holds, instead of jumping ahead by the time lost. Jumping
        # ahead put the program's velocity of a later time (a few ms further into a deceleration) out of the one
        # cycle's acceleration window (9d): LP (9) had no answer and the robot made a ramp stop (0.5 s) for one late
        # tick. The time lost slows the program by as much; an early decision (an event cycle) moves on by less.
        step_s = min(elapsed_s, self.period_s)
        self.last_mono_ns = now_mono_ns
        self._advance(step_s * self.delta_prev)
        self.q_ref_rad = self.q_ref_rad + step_s * self.qd_prev_radps
        if not self.followed(q_meas_rad, now_mono_ns, round_trip_s):
            self.start_from(q_meas_rad, qd_meas_radps)
            self.reference_restarts += 1
            self.sent_mono_ns[:] = -1  # what was sent before the robot stopped following says nothing now
        q_ref = self.q_ref_rad
        qd_prev = self.qd_prev_radps[self.active]
        safety = self._rows(q_meas_rad, links, rows, humans)
        if safety is None:
            cap(0.0)
            qd_stop, ratio = open_control.ramp_stop_ratio(qd_prev, self.limits, self.period_s)
            solution = Solution(qd_stop, self.delta_prev * ratio, "ramp_stop:inputs")
        else:
            task, q_prog = self.task(q_ref)
            jac_a, jac_b = self.link_jacobians(q_meas_rad)
            away = np.zeros(self.active.size)
            if closest_point_m is not None and link_distance_m is not None:
                away = open_control.away_from_people(
                    jac_a,
                    jac_b,
                    links.p_a_world,
                    links.p_b_world,
                    link_distance_m,
                    closest_point_m,
                    AWAY_INFLUENCE_M,
                    AWAY_GAIN_RADPS,
                )
            posture = POSTURE_GAIN_PER_S * (q_prog - q_ref)[self.active]
            qd_self = open_control.self_motion_reference(task, max(self.delta_prev, 0.0), posture, away)
            solution = self.lp.decide(
                safety,
                task,
                qd_prev,
                q_ref[self.active],
                self.limits,
                self.period_s,
                qd_self,
                cap,
                self.robot.link_names,
                self.delta_prev,
                bound_if_infeasible,
            )
        qd = np.zeros_like(q_ref)
        qd[self.active] = solution.qd_radps
        self.qd_prev_radps = qd
        self.delta_prev = solution.delta
        q_next = q_ref + self.period_s * qd
        self.sent_q_rad[self.sent_next] = q_next[self.active]
        self.sent_mono_ns[self.sent_next] = now_mono_ns
        self.sent_next = (self.sent_next + 1) % SENT_KEPT
        n_rows = 0 if safety is None else int(safety.f_m2.size)
        dropped = 0 if safety is None else safety.dropped
        duration_s = self.trajectory.duration_s
        program_cycles = self.progress_tau_s() / duration_s if duration_s > 0.0 else 0.0
        return OpenCommand(q_next, qd, solution, n_rows, dropped, self.reference_restarts, program_cycles)

    def _rows(
        self, q_meas_rad: FloatArray, links: LinkKinematics, rows: ConstraintRows | None, humans: HumanCapsules
    ) -> SafetyRows | None:
        if rows is None:
            return None
        if not humans.n_capsules:
            n = self.active.size
            return SafetyRows(np.zeros((0, n)), np.zeros(0), np.zeros(0, np.intp), np.zeros(0, np.intp), 0)
        jac_a, jac_b = self.link_jacobians(q_meas_rad)
        return open_control.safety_rows(
            jac_a,
            jac_b,
            links.p_a_world,
            links.p_b_world,
            humans.h_a_world,
            humans.h_b_world,
            rows.f_m2,
            rows.horizon_s,
            self.limits.qd_max_radps,
        )
