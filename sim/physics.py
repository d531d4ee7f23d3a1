"""The stand-in's body: MuJoCo physics with rate-limited position servos, motor modes and modelled temperatures.

Callers only take short locks. set_targets swaps in a new goal array (the stepping thread reads whichever is
current) and state() reads the joints as the last batch of steps published them, so the two the server calls on
every pose and joint-state tick never wait for a batch. Stepping happens in one of two ways: `run`, a thread
stepping at real-time factor 1 (dropping a backlog past MAX_LAG_S rather than sprinting through it), or
`step_to`, called by a simulated clock's loop (simclock) as it advances.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

from robot_models import RobotModel
from robot_models.types import MotorMode

from .thermal import ThermalModel

log = logging.getLogger(__name__)
_RAD_PER_DEG = math.pi / 180.0  # what np.radians multiplies by
WARN_EVERY_S = 60.0  # "physics is behind" at most this often, with a count of the times since

State = tuple[tuple[float, ...], ...]  # (positions, velocities, setpoints, efforts, (sim time,))


@dataclass(frozen=True)
class JointSnapshot:
    """Joint state in canonical order, degrees and deg/s."""

    names: tuple[str, ...]
    positions: tuple[float, ...]
    velocities: tuple[float, ...]
    targets: tuple[float, ...]  # the goals the caller set (after clamping)
    setpoints: tuple[float, ...]  # the rate-limited servo setpoints on their way to the goals
    efforts: tuple[float, ...]  # actuator torque, N m
    modes: tuple[MotorMode, ...]
    stamp_monotonic: float
    stamp_wall: float
    sim_time: float

    def position(self, name: str) -> float:
        return self.positions[self.names.index(name)]


@dataclass(frozen=True)
class PhysicsStats:
    realtime_factor: float  # simulated seconds per wall second over the last ~1 s
    sim_time: float
    steps: int
    lag_s: float  # how far simulation time trails wall time right now
    resyncs: int  # times the loop gave up catching up and dropped the backlog
    step_us: float  # mean cost of one mj_step plus servo update, microseconds


class Physics:
    """The robot's joints in the scene's MuJoCo model: goals, servo setpoints, motor modes, temperatures."""

    STEPS_PER_LOCK = 10  # bounds how long a caller can wait for the state lock (about 10 steps' cost)
    MAX_LAG_S = 0.25  # beyond this the real-time loop drops its backlog instead of sprinting to catch up
    WARN_LAG_S = 0.05

    def __init__(self, robot: RobotModel, model: mujoco.MjModel, *, ambient_temperature_c: float) -> None:
        self.robot = robot
        self.model = m = model
        self.data = mujoco.MjData(m)
        self.dt = float(m.opt.timestep)
        self.names = robot.names
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.names]
        self._qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self._dadr = np.array([m.jnt_dofadr[j] for j in jids])
        self._act = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in self.names])
        if (self._act < 0).any() or (np.array(jids) < 0).any():
            raise ValueError("the scene's model lacks a joint or actuator named as in the robot description")
        # The head's joints (HeadYaw, HeadPitch) in qpos: a camera frame carries the pose its render used.
        self._head_qadr = tuple(int(self._qadr[self.names.index(n)]) for n in robot.part_joints("head"))
        self._lower = np.array([j.lower for j in robot.joints])
        self._upper = np.array([j.upper for j in robot.joints])
        # plain floats and a name index for set_targets, called for every teleop command (numpy costs more there)
        self._index = {n: i for i, n in enumerate(self.names)}
        self._lower_deg = [float(v) for v in self._lower]
        self._upper_deg = [float(v) for v in self._upper]
        self._caps = np.array([j.max_velocity for j in robot.joints])
        self._step_limit = self._caps * self.dt
        self._gain = m.actuator_gainprm[self._act, 0].copy()
        self._bias = m.actuator_biasprm[self._act, :3].copy()
        self._body_of = np.array([m.jnt_bodyid[j] for j in jids])
        self._gravcomp = m.body_gravcomp.copy()

        home = np.array([j.home for j in robot.joints])
        self.data.qpos[self._qadr] = np.radians(home)
        self._goal = home.copy()
        self._setpoint = home.copy()
        self._gap, self._ctrl = np.empty_like(home), np.empty_like(home)  # step's buffers
        self.data.ctrl[self._act] = np.radians(home)
        self._modes = [MotorMode.ON] * len(self.names)
        mujoco.mj_forward(m, self.data)
        self.thermal = ThermalModel(len(self.names), ambient_temperature_c)

        self.lock = threading.Lock()  # guards data, setpoints, modes, temperatures, stats
        self._goal_lock = threading.Lock()  # serialises goal writers; the goal array is replaced, never edited
        self.state: State = self.capture()  # the joints as the last batch published them
        self.steps = 0
        self._resyncs = 0
        self._lag = 0.0
        self._step_cost = 0.0
        self._rtf_window: collections.deque[tuple[float, float]] = collections.deque(maxlen=64)
        self._last_warn = -math.inf
        self._behind = 0  # times behind since the last warning, and by how much at worst (s)
        self._worst_lag = 0.0

    # ---- commands ------------------------------------------------------------------------------------------------
    def set_targets(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Set joint goals in degrees; returns the goals applied after clamping to the joint limits.
        Joints whose motor is not ON ignore the command and are left out of the result."""
        index, lower, upper = self._index, self._lower_deg, self._upper_deg
        applied = []
        for name, deg in targets.items():
            i = index.get(name)
            if i is None:
                self.robot.joint(name)  # KeyError naming the valid joints
                i = self.names.index(name)
            value = float(deg)
            if not math.isfinite(value):
                raise ValueError(f"joint {name}: target must be a finite number of degrees, got {deg!r}")
            applied.append((i, min(max(value, lower[i]), upper[i])))
        out = {}
        with self._goal_lock:
            goal = self._goal.copy()
            for i, v in applied:
                if self._modes[i] is MotorMode.ON:
                    goal[i] = v
                    out[self.names[i]] = v
            self._goal = goal
        return out

    def set_scene_joint(self, name: str, deg: float) -> None:
        """Put a joint of the scene's own (not the robot's: no motor drives it) at deg and still (a pupil's neck)."""
        m = self.model
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0 or name in self._index:
            raise KeyError(f"no scene joint {name!r}")
        with self.lock:
            self.data.qpos[m.jnt_qposadr[j]] = math.radians(deg)
            self.data.qvel[m.jnt_dofadr[j]] = 0.0
            mujoco.mj_kinematics(m, self.data)

    def set_velocity_caps(self, caps: Mapping[str, float]) -> None:
        """Change velocity caps (deg/s) at run time; validated by RobotModel.with_velocity_caps."""
        robot = self.robot.with_velocity_caps(caps)
        with self.lock:
            self.robot = robot
            self._caps = np.array([j.max_velocity for j in robot.joints])
            self._step_limit = self._caps * self.dt

    def set_motor_mode(self, joints: Iterable[str], mode: MotorMode | int) -> None:
        """Switch joints between ON, OFF (limp) and BRAKE (hold here). Going ON holds the current position,
        so a stale goal cannot make the joint jump."""
        mode = MotorMode(mode)
        idx = [self.names.index(self.robot.joint(n).name) for n in joints]
        with self.lock, self._goal_lock:
            m = self.model
            goal = self._goal.copy()
            for i in idx:
                a, b = self._act[i], self._body_of[i]
                here = math.degrees(self.data.qpos[self._qadr[i]])
                here = min(max(here, self._lower[i]), self._upper[i])
                goal[i] = self._setpoint[i] = here
                self.data.ctrl[a] = math.radians(here)
                if mode is MotorMode.OFF:
                    m.actuator_gainprm[a, 0] = 0.0
                    m.actuator_biasprm[a, :3] = 0.0
                    m.body_gravcomp[b] = 0.0
                else:
                    m.actuator_gainprm[a, 0] = self._gain[i]
                    m.actuator_biasprm[a, :3] = self._bias[i]
                    m.body_gravcomp[b] = self._gravcomp[b]
                self._modes[i] = mode
            self._goal = goal
            self.state = self.capture()

    # ---- reading -------------------------------------------------------------------------------------------------
    def capture(self) -> State:
        """(positions, velocities, setpoints, efforts, (sim time,)) from the physics state; the caller holds the
        lock (or nothing steps)."""
        d = self.data
        return (tuple(np.degrees(d.qpos[self._qadr]).tolist()), tuple(np.degrees(d.qvel[self._dadr]).tolist()),
                tuple(self._setpoint.tolist()), tuple(d.actuator_force[self._act].tolist()), (float(d.time),))

    def goals(self) -> tuple[tuple[float, ...], tuple[MotorMode, ...]]:
        """The goals as set and the motor modes (no lock: the goal array is replaced, never edited)."""
        return tuple(self._goal.tolist()), tuple(self._modes)

    def targets(self) -> dict[str, float]:
        with self.lock:
            return dict(zip(self.names, map(float, self._goal)))

    def temperatures(self) -> dict[str, float]:
        with self.lock:
            return dict(zip(self.names, map(float, self.thermal.temperature)))

    def scene_state(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Copies of qpos and qvel, and the simulated time: what a picture of the scene needs."""
        with self.lock:
            return self.data.qpos.copy(), self.data.qvel.copy(), float(self.data.time)

    def head_pose(self, qpos: np.ndarray) -> tuple[float, float]:
        """(HeadYaw, HeadPitch) in degrees in a copy of qpos (scene_state's): the pose a picture of it shows."""
        yaw, pitch = self._head_qadr
        return math.degrees(float(qpos[yaw])), math.degrees(float(qpos[pitch]))

    def stats(self) -> PhysicsStats:
        with self.lock:
            window = list(self._rtf_window)
            sim_time, steps, lag, resyncs, cost = self.data.time, self.steps, self._lag, self._resyncs, self._step_cost
        rtf = float("nan")
        if len(window) >= 2 and window[-1][0] > window[0][0]:
            rtf = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0])
        return PhysicsStats(rtf, sim_time, steps, lag, resyncs, cost * 1e6)

    # ---- stepping ------------------------------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> None:
        """The real-time loop, in a thread of its own until `stop` is set."""
        d = self.data
        t0 = time.monotonic()
        sim0 = d.time
        done = 0
        cost_avg = 0.0
        last_sample = -math.inf
        try:
            while not stop.is_set():
                now = time.monotonic()
                due = int((now - t0) / self.dt) - done
                if due * self.dt > self.MAX_LAG_S:
                    self._warn_behind(due * self.dt, resync=True)
                    t0 = now - done * self.dt  # drop the backlog: real time goes on without us
                    with self.lock:
                        self._resyncs += 1
                    due = 1
                if due <= 0:
                    stop.wait(max(0.0, t0 + (done + 1) * self.dt - now))
                    continue
                if due * self.dt > self.WARN_LAG_S:
                    self._warn_behind(due * self.dt, resync=False)
                c0 = time.perf_counter()
                batch = min(due, self.STEPS_PER_LOCK)
                with self.lock:
                    self._step(batch)
                    done = self.steps
                    self.state = self.capture()
                    after = time.monotonic()
                    self._lag = max(0.0, (after - t0) - done * self.dt)
                    if after - last_sample >= 0.05:
                        self._rtf_window.append((after, d.time - sim0))
                        last_sample = after
                cost = (time.perf_counter() - c0) / batch
                cost_avg = cost if cost_avg == 0.0 else 0.98 * cost_avg + 0.02 * cost
                self._step_cost = cost_avg
        except Exception:  # pragma: no cover - logged so a dead physics thread is visible
            log.exception("stand-in physics thread died")

    def step_to(self, t: float) -> None:
        """A simulated clock's loop thread: step to simulated time t."""
        with self.lock:
            due = int(math.floor(t / self.dt + 1e-9)) - self.steps
            if due > 0:
                self._step(due)
                self.state = self.capture()

    def _step(self, n: int) -> None:
        """n physics steps (the caller holds the lock). Rate limit: the setpoint moves toward the goal by at most
        cap * dt a step. Joints not ON have goal == setpoint (see set_motor_mode), so they stay put here. While
        every setpoint has reached its goal the control is constant, and MuJoCo takes the steps in one call."""
        m, d = self.model, self.data
        every = self.thermal.EVERY_STEPS
        while n > 0:
            gap = np.subtract(self._goal, self._setpoint, out=self._gap)
            if not np.count_nonzero(gap):  # (ndarray.any() goes through a Python wrapper: slower)
                k = min(n, every - self.steps % every)
                mujoco.mj_step(m, d, k)
            else:
                k = 1
                # np.clip and np.radians, as ufuncs into buffers: their wrappers cost as much as the step itself
                limit = self._step_limit
                np.minimum(np.maximum(gap, np.negative(limit, out=self._ctrl), out=gap), limit, out=gap)
                np.add(self._setpoint, gap, out=self._setpoint)
                d.ctrl[self._act] = np.multiply(self._setpoint, _RAD_PER_DEG, out=self._ctrl)
                mujoco.mj_step(m, d)
            n -= k
            self.steps += k
            if self.steps % every == 0:
                self.thermal.update(d.actuator_force[self._act], every * self.dt)

    def _warn_behind(self, lag: float, *, resync: bool) -> None:
        """The first time at once, then at most once a WARN_EVERY_S with how often and how far since: a busy
        machine falls behind again and again, and one line a minute says so."""
        now = time.monotonic()
        self._behind += 1
        self._worst_lag = max(self._worst_lag, lag)
        if now - self._last_warn < WARN_EVERY_S:
            return
        if self._behind == 1:
            log.warning("stand-in physics is %.0f ms behind real time%s (the machine is overloaded)",
                        lag * 1e3, "; dropping the backlog" if resync else "")
        else:
            log.warning("stand-in physics fell behind real time %d times in the last %.0f s, by up to %.0f ms "
                        "(the machine is overloaded)", self._behind, now - self._last_warn, self._worst_lag * 1e3)
        self._last_warn, self._behind, self._worst_lag = now, 0, 0.0
