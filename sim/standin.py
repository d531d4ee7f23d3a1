"""The stand-in robot: MuJoCo physics in real time, rate-limited position servos, a rendered head camera.

Three kinds of thread touch it:
- the physics thread steps MuJoCo at real-time factor 1 and moves each servo's setpoint toward its goal by at
  most max_velocity * dt per step, so no joint outruns its cap whatever the caller sends;
- the render thread decides what to draw and when: the face texture, the head camera (only while someone
  watches: into the frame ring's shared memory, and as JPEG only while a JPEG consumer watches), snapshots. The
  drawing happens in a render process (render_process.py: the OpenGL context, llvmpipe, JPEG, the face), at a lower CPU priority and with its own GIL, so the server's event loop is not
  delayed by it; the thread sends it the joint state, copied from the physics state under a lock held only for
  the copy, and waits for the picture. If that process dies, the camera closes (frame waiters and
  camera-closed listeners are told, snapshots fail with the reason) while the physics goes on: the robot holds;
- callers (the asyncio loop, tests) only take short locks: every public method returns in microseconds,
  except snapshot() and the wait_* helpers, which block by design and say so. The two the server calls on every
  pose and joint-state tick never wait for a physics batch: set_targets swaps in a new goal array (the physics
  thread reads whichever is current), and joint_state reads the state the physics thread publishes after each
  batch. Waiting on the batch's lock held the event loop for a millisecond at a time (bench/teleop.py).
On a simulated clock (simclock; replays and studies at `--speed max`) there is no physics thread: the stand-in
attaches to the clock, which steps the physics and asks for camera frames (at camera_fps in simulated time,
while someone watches) in its loop's thread as it advances, so both move in lock-step with simulated time.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass

import mujoco
import numpy as np

from robot_models import RobotModel, load_qtrobot
from robot_models.mjcf import HEAD_CAMERA
from robot_models.types import CameraFrame, MotorMode
from simclock import WALL, Clock
from worker_process.frame_ring import FrameRing

from .face import normalise_emotion
from .render_process import RenderProcess, RenderProcessError
from .scene import ClassroomScene, build_classroom

log = logging.getLogger(__name__)
_RAD_PER_DEG = math.pi / 180.0  # what np.radians multiplies by


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


class StandIn:
    """QTrobot in a MuJoCo classroom, running in real time in background threads.

    Use as a context manager or call close(). Joint names, limits and caps come from `robot`.
    antialias defaults to 0 (no MSAA): without a GPU, 4x MSAA triples the render time (bench/standin.py:
    about 27 ms against 9 ms a 640x480 frame on 2 loaded cores) and costs the 30 fps target.
    render_nice: how much lower the render process's CPU priority is than this process's (RenderProcess.NICE);
    none on a simulated clock, where the clock waits for each frame (a niced renderer starves on a busy machine).
    """

    FACE_ANIMATION_HZ = 12.0
    STEPS_PER_LOCK = 10  # bounds how long a caller can wait for the state lock (about 10 steps' cost)
    THERMAL_GAIN = 0.02  # K above ambient per (N m)^2 of steady torque
    THERMAL_TAU_S = 120.0
    MAX_LAG_S = 0.25  # beyond this the physics loop drops its backlog instead of sprinting to catch up
    WARN_LAG_S = 0.05
    # The render process holds nothing to save: closing, it gets this long to exit, then is killed. At nice +10 on a
    # busy machine its orderly exit took 4.5 s or more (0.5 s idle), which outlasted the 5 s close() used to wait.
    RENDER_EXIT_S = 1.0
    # What close() waits for the render thread: one call in flight (the worker is killed past its reply timeout),
    # then the worker's exit; the physics thread wakes on the stop event at once.
    STOP_TIMEOUT_S = RenderProcess.REPLY_TIMEOUT_S + RENDER_EXIT_S + 5.0

    def __init__(
        self,
        robot: RobotModel | None = None,
        *,
        scene: ClassroomScene | None = None,
        camera_width: int | None = None,
        camera_height: int | None = None,
        camera_fps: float = 30.0,
        jpeg_quality: int = 80,
        antialias: int = 0,
        shadows: bool = False,
        initial_emotion: str = "neutral",
        ambient_temperature_c: float = 30.0,
        render_nice: int = RenderProcess.NICE,
        clock: Clock = WALL,
    ) -> None:
        self.clock = clock
        self.robot = robot or load_qtrobot()
        cam = self.robot.camera
        self.camera_width = int(camera_width or (cam.width if cam else 640))
        self.camera_height = int(camera_height or (cam.height if cam else 480))
        if not 0 < camera_fps <= 120:
            raise ValueError(f"camera_fps must be in (0, 120], got {camera_fps}")
        if not 1 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in 1..100, got {jpeg_quality}")
        self.camera_fps = float(camera_fps)
        self.jpeg_quality = int(jpeg_quality)
        self.render_nice = 0 if clock.simulated else int(render_nice)
        self.scene = scene or build_classroom(
            self.robot, shadows=shadows, antialias=antialias,
            offscreen_size=(max(1280, self.camera_width), max(720, self.camera_height)))
        self.model = self.scene.model
        m = self.model
        if m.vis.global_.offwidth < self.camera_width or m.vis.global_.offheight < self.camera_height:
            raise ValueError(f"camera size {self.camera_width}x{self.camera_height} exceeds the scene's offscreen "
                             f"buffer {m.vis.global_.offwidth}x{m.vis.global_.offheight}; build the scene with a "
                             "larger offscreen_size")
        self.data = mujoco.MjData(m)
        self.dt = float(m.opt.timestep)
        self.names = self.robot.names
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.names]
        self._qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self._dadr = np.array([m.jnt_dofadr[j] for j in jids])
        self._act = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in self.names])
        if (self._act < 0).any() or (np.array(jids) < 0).any():
            raise ValueError("the scene's model lacks a joint or actuator named as in the robot description")
        self._lower = np.array([j.lower for j in self.robot.joints])
        self._upper = np.array([j.upper for j in self.robot.joints])
        # plain floats and a name index for set_targets, called for every teleop command (numpy costs more there)
        self._index = {n: i for i, n in enumerate(self.names)}
        self._lower_deg = [float(v) for v in self._lower]
        self._upper_deg = [float(v) for v in self._upper]
        self._caps = np.array([j.max_velocity for j in self.robot.joints])
        self._step_limit = self._caps * self.dt
        self._gain = m.actuator_gainprm[self._act, 0].copy()
        self._bias = m.actuator_biasprm[self._act, :3].copy()
        self._body_of = np.array([m.jnt_bodyid[j] for j in jids])
        self._gravcomp = m.body_gravcomp.copy()

        home = np.array([j.home for j in self.robot.joints])
        self.data.qpos[self._qadr] = np.radians(home)
        self._goal = home.copy()
        self._setpoint = home.copy()
        self._gap, self._ctrl = np.empty_like(home), np.empty_like(home)  # _step's buffers
        self.data.ctrl[self._act] = np.radians(home)
        self._modes = [MotorMode.ON] * len(self.names)
        mujoco.mj_forward(m, self.data)

        # Thermal model for motor status (a stand-in has no sensors): each motor warms with the square of its
        # torque and cools toward ambient (THERMAL_GAIN, THERMAL_TAU_S). Modelled, not measured.
        self._ambient = float(ambient_temperature_c)
        self._temperature = np.full(len(self.names), self._ambient)

        self._lock = threading.Lock()  # guards data, setpoints, modes, stats
        self._goal_lock = threading.Lock()  # serialises goal writers; the goal array is replaced, never edited
        self._state = self._capture()  # the joints as the physics thread last published them
        self._stop = threading.Event()
        self._steps = 0
        self._resyncs = 0
        self._lag = 0.0
        self._step_cost = 0.0
        self._rtf_window: collections.deque[tuple[float, float]] = collections.deque(maxlen=64)
        self._last_warn = -math.inf

        # Render-side state, guarded by _render_cond's lock.
        self._render_cond = threading.Condition()
        self._camera_subscribers = 0
        self._jpeg_subscribers = 0  # of the camera's subscribers, those that want JPEG (the others read the ring)
        self._emotion = normalise_emotion(initial_emotion)
        self._talking_until = 0.0
        self._voice = (0.0, -math.inf)  # (level, monotonic time it was set)
        self._face_version = 0  # bumped on every request that changes the face
        self._face_applied = -1
        self._face_image: np.ndarray | None = None
        self._snapshots: collections.deque[tuple[str, int, int, Future]] = collections.deque()
        self._frame: CameraFrame | None = None
        self._frame_cond = threading.Condition()
        self._frame_listeners: list[Callable[[CameraFrame], None]] = []
        self._seq = 0
        self._render_error: BaseException | None = None
        self._renderer: RenderProcess | None = None
        # Raw frames in shared memory for the video encoder; released when the renderer stops (closed or dead).
        self._ring = FrameRing.create(self.camera_width, self.camera_height)
        self._camera_closed_listeners: list[Callable[[], None]] = []
        self._render_ready = threading.Event()
        self._frame_requests: collections.deque[tuple[tuple, tuple[float, float, float], Future]] = \
            collections.deque()  # simulated clock: frames the clock asks for, drawn by the render thread
        self._next_frame_at = 0.0  # simulated clock: when the next camera frame is due

        self._physics_thread = threading.Thread(target=self._physics_loop, name="standin-physics", daemon=True)
        self._render_thread = threading.Thread(target=self._render_loop, name="standin-render", daemon=True)
        # The renderer starts first: starting its process and a GL context costs a second of CPU that would
        # otherwise make the physics loop start behind real time.
        self._render_thread.start()
        if not self._render_ready.wait(RenderProcess.START_TIMEOUT_S + 5) or self._render_error is not None:
            self.close()
            raise RuntimeError(f"the stand-in's renderer did not start ({self._render_error!r}); MuJoCo needs "
                               "MUJOCO_GL=egl (or osmesa) and a working libEGL on a headless machine")
        if clock.simulated:
            clock.attach(self)  # type: ignore[attr-defined]
        else:
            self._physics_thread.start()

    # ----------------------------------------------------------------------------------------------- joints
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

    def set_velocity_caps(self, caps: Mapping[str, float]) -> None:
        """Change velocity caps (deg/s) at run time; validated by RobotModel.with_velocity_caps."""
        robot = self.robot.with_velocity_caps(caps)
        with self._lock:
            self.robot = robot
            self._caps = np.array([j.max_velocity for j in robot.joints])
            self._step_limit = self._caps * self.dt

    def set_motor_mode(self, joints: Iterable[str], mode: MotorMode | int) -> None:
        """Switch joints between ON, OFF (limp) and BRAKE (hold here). Going ON holds the current position,
        so a stale goal cannot make the joint jump."""
        mode = MotorMode(mode)
        idx = [self.names.index(self.robot.joint(n).name) for n in joints]
        with self._lock, self._goal_lock:
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
            self._state = self._capture()

    def _capture(self) -> tuple[tuple[float, ...], ...]:
        """(positions, velocities, setpoints, efforts, (sim time,)) from the physics state; the caller holds _lock
        (or no physics thread runs)."""
        d = self.data
        return (tuple(np.degrees(d.qpos[self._qadr]).tolist()), tuple(np.degrees(d.qvel[self._dadr]).tolist()),
                tuple(self._setpoint.tolist()), tuple(d.actuator_force[self._act].tolist()), (float(d.time),))

    def joint_state(self) -> JointSnapshot:
        """The joints as of the physics thread's last batch (at most STEPS_PER_LOCK steps old), with the goals
        as set; on a simulated clock, as of the clock's time; without a physics thread, as of now."""
        if self._physics_thread.is_alive() or self.clock.simulated:
            q, v, sp, f, (t,) = self._state
        else:
            with self._lock:
                q, v, sp, f, (t,) = self._capture()
        goal, modes = self._goal, tuple(self._modes)
        return JointSnapshot(self.names, q, v, tuple(goal.tolist()), sp, f, modes, self.clock.monotonic(),
                             self.clock.time(), t)

    def joint_positions(self) -> dict[str, float]:
        s = self.joint_state()
        return dict(zip(s.names, s.positions))

    def targets(self) -> dict[str, float]:
        with self._lock:
            return dict(zip(self.names, map(float, self._goal)))

    def motor_temperatures(self) -> dict[str, float]:
        """Modelled motor temperatures, degrees Celsius (see the thermal model in __init__)."""
        with self._lock:
            return dict(zip(self.names, map(float, self._temperature)))

    def physics_stats(self) -> PhysicsStats:
        with self._lock:
            window = list(self._rtf_window)
            sim_time, steps, lag, resyncs, cost = self.data.time, self._steps, self._lag, self._resyncs, self._step_cost
        rtf = float("nan")
        if len(window) >= 2 and window[-1][0] > window[0][0]:
            rtf = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0])
        return PhysicsStats(rtf, sim_time, steps, lag, resyncs, cost * 1e6)

    # ------------------------------------------------------------------------------------------------- face
    def set_emotion(self, name: str) -> None:
        """Show an emotion ("happy" or "QT/happy"); the render thread redraws the face texture."""
        emotion = normalise_emotion(name)
        with self._render_cond:
            self._emotion = emotion
            self._face_version += 1
            self._render_cond.notify_all()

    @property
    def emotion(self) -> str:
        return self._emotion

    def speak(self, duration_s: float) -> None:
        """Animate the talking mouth for duration_s seconds from now (returns at once)."""
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"speech duration must be a finite number of seconds >= 0, got {duration_s!r}")
        with self._render_cond:
            self._talking_until = self.clock.monotonic() + duration_s
            self._face_version += 1
            self._render_cond.notify_all()

    def is_talking(self) -> bool:
        return self.clock.monotonic() < self._talking_until

    VOICE_HOLD_S = 0.25  # the mouth closes this long after the last piece of voice

    def set_voice_level(self, level: float) -> None:
        """The operator's voice, as the robot plays it (0..1): the mouth opens with it (returns at once)."""
        level = min(1.0, max(0.0, float(level))) if math.isfinite(level) else 0.0
        with self._render_cond:
            self._voice = (level, self.clock.monotonic())
            self._render_cond.notify_all()

    @property
    def voice_level(self) -> float:
        """The voice level the face shows now (0 once the voice has stopped for VOICE_HOLD_S)."""
        level, at = self._voice
        return level if self.clock.monotonic() - at < self.VOICE_HOLD_S else 0.0

    def face_image(self) -> np.ndarray | None:
        """A copy of the face texture as last uploaded (RGB), or None before the first upload."""
        with self._render_cond:
            return None if self._face_image is None else self._face_image.copy()

    def wait_face(self, timeout: float = 2.0) -> bool:
        """Block until the render thread has applied every face change requested so far."""
        deadline = time.monotonic() + timeout
        with self._render_cond:
            target = self._face_version
            while self._face_applied < target:
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set():
                    return False
                self._render_cond.wait(left)
            return True

    # ----------------------------------------------------------------------------------------------- camera
    def start_camera(self, jpeg: bool = True) -> None:
        """Count one more viewer; frames are rendered while at least one is counted, and compressed to JPEG while
        at least one counted with `jpeg` (the others read the frame ring: `frame_ring`)."""
        with self._render_cond:
            self._camera_subscribers += 1
            self._jpeg_subscribers += bool(jpeg)
            self._render_cond.notify_all()

    def stop_camera(self, jpeg: bool = True) -> None:
        with self._render_cond:
            self._camera_subscribers = max(0, self._camera_subscribers - 1)
            if jpeg:
                self._jpeg_subscribers = max(0, self._jpeg_subscribers - 1)
            self._render_cond.notify_all()

    @property
    def frame_ring(self) -> FrameRing:
        """The shared memory the camera's raw frames go to (closed once the renderer has stopped)."""
        return self._ring

    @property
    def camera_subscribers(self) -> int:
        return self._camera_subscribers

    def add_frame_listener(self, callback: Callable[[CameraFrame], None]) -> None:
        """Call `callback(frame)` from the render thread for every new frame; it must be quick and thread-safe
        (an asyncio user hands off with loop.call_soon_threadsafe)."""
        with self._frame_cond:
            self._frame_listeners = [*self._frame_listeners, callback]

    def remove_frame_listener(self, callback: Callable[[CameraFrame], None]) -> None:
        with self._frame_cond:
            self._frame_listeners = [c for c in self._frame_listeners if c is not callback]

    def add_camera_closed_listener(self, callback: Callable[[], None]) -> None:
        """Call `callback()` (from the render thread) once the camera has closed for good: on close(), or when the
        render process died. Quick and thread-safe, as a frame listener."""
        with self._frame_cond:
            self._camera_closed_listeners = [*self._camera_closed_listeners, callback]

    @property
    def render_error(self) -> BaseException | None:
        """Why the renderer stopped (its process died, or it did not start), or None while it works."""
        return self._render_error

    @property
    def render_pid(self) -> int | None:
        """The render process's id (for tools and tests), or None before it started."""
        return None if self._renderer is None else self._renderer.pid

    def latest_frame(self) -> CameraFrame | None:
        return self._frame

    def wait_frame(self, after_seq: int = 0, timeout: float = 2.0) -> CameraFrame | None:
        """Block until a frame newer than after_seq exists (for tests and tools; not for the event loop)."""
        deadline = time.monotonic() + timeout
        with self._frame_cond:
            while self._frame is None or self._frame.seq <= after_seq:
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set() or self._render_error is not None:
                    return None
                self._frame_cond.wait(left)
            return self._frame

    def snapshot(self, camera: str = HEAD_CAMERA, width: int | None = None, height: int | None = None,
                 timeout: float = 5.0) -> np.ndarray:
        """Render one RGB image from a named camera of the scene. Blocks up to `timeout` (run it in a thread
        when called from asyncio)."""
        if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            names = [mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(self.model.ncam)]
            raise KeyError(f"no camera {camera!r} in the scene; cameras: {names}")
        fut: Future = Future()
        with self._render_cond:
            if self._stop.is_set():
                raise RuntimeError("the stand-in is closed")
            if self._render_error is not None:
                raise RuntimeError(f"the stand-in's renderer died: {self._render_error}")
            self._snapshots.append((camera, int(width or self.camera_width), int(height or self.camera_height), fut))
            self._render_cond.notify_all()
        return fut.result(timeout)

    # -------------------------------------------------------------------------------------------- lifecycle
    def close(self) -> None:
        """Stop both threads (promptly: they wake on the stop event) and the render process."""
        self._stop.set()
        if self.clock.simulated:
            self.clock.detach(self)  # type: ignore[attr-defined]
        with self._render_cond:
            self._render_cond.notify_all()
        with self._frame_cond:
            self._frame_cond.notify_all()
        for t in (self._physics_thread, self._render_thread):
            if t.is_alive() and t is not threading.current_thread():
                t.join(timeout=self.STOP_TIMEOUT_S)
                if t.is_alive():
                    log.error("stand-in thread %s did not stop within %g s", t.name, self.STOP_TIMEOUT_S)

    @property
    def closed(self) -> bool:
        return self._stop.is_set()

    def __enter__(self) -> StandIn:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -------------------------------------------------------------------------------------------- internals
    def _physics_loop(self) -> None:
        d = self.data
        t0 = time.monotonic()
        sim0 = d.time
        done = 0
        cost_avg = 0.0
        last_sample = -math.inf
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                due = int((now - t0) / self.dt) - done
                if due * self.dt > self.MAX_LAG_S:
                    self._warn_behind(due * self.dt, resync=True)
                    t0 = now - done * self.dt  # drop the backlog: real time goes on without us
                    with self._lock:
                        self._resyncs += 1
                    due = 1
                if due <= 0:
                    self._stop.wait(max(0.0, t0 + (done + 1) * self.dt - now))
                    continue
                if due * self.dt > self.WARN_LAG_S:
                    self._warn_behind(due * self.dt, resync=False)
                c0 = time.perf_counter()
                batch = min(due, self.STEPS_PER_LOCK)
                with self._lock:
                    self._step(batch)
                    done = self._steps
                    self._state = self._capture()
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

    THERMAL_EVERY = 50  # steps between thermal-model updates (0.1 s at 2 ms)

    def _step(self, n: int) -> None:
        """n physics steps (the caller holds the lock). Rate limit: the setpoint moves toward the goal by at most
        cap * dt a step. Joints not ON have goal == setpoint (see set_motor_mode), so they stay put here. While
        every setpoint has reached its goal the control is constant, and MuJoCo takes the steps in one call."""
        m, d = self.model, self.data
        while n > 0:
            gap = np.subtract(self._goal, self._setpoint, out=self._gap)
            if not np.count_nonzero(gap):  # (ndarray.any() goes through a Python wrapper: slower)
                k = min(n, self.THERMAL_EVERY - self._steps % self.THERMAL_EVERY)
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
            self._steps += k
            if self._steps % self.THERMAL_EVERY == 0:
                f = d.actuator_force[self._act]
                self._temperature += (self._ambient + self.THERMAL_GAIN * f * f - self._temperature) * (
                    self.THERMAL_EVERY * self.dt / self.THERMAL_TAU_S)

    # ---------------------------------------------------------------------- on a simulated clock (simclock)
    def next_due(self) -> float:
        """When the camera's next frame is due in simulated time (none while nobody watches)."""
        return self._next_frame_at if self._camera_subscribers > 0 and self._render_error is None else math.inf

    def advance_to(self, t: float) -> None:
        """The clock's loop thread: step the physics to simulated time t; draw the camera frame due at t."""
        if self._stop.is_set():
            return
        with self._lock:
            due = int(math.floor(t / self.dt + 1e-9)) - self._steps
            if due > 0:
                self._step(due)
                self._state = self._capture()
        if self._camera_subscribers <= 0 or self._render_error is not None:
            self._next_frame_at = max(self._next_frame_at, t)
            return
        if t >= self._next_frame_at:
            self._next_frame_at = t + 1.0 / self.camera_fps
            with self._lock:
                state = (self.data.qpos.copy(), self.data.qvel.copy(), self.data.time)
            fut: Future = Future()
            with self._render_cond:
                self._frame_requests.append((state, (self.clock.monotonic(), self.clock.time(), state[2]), fut))
                self._render_cond.notify_all()
            try:
                fut.result(RenderProcess.START_TIMEOUT_S + 30)
            except Exception as exc:  # the renderer died: the camera closes, the physics goes on
                log.error("a simulated-time camera frame failed: %s", exc)

    def _warn_behind(self, lag: float, *, resync: bool) -> None:
        now = time.monotonic()
        if now - self._last_warn >= 5.0:
            self._last_warn = now
            log.warning("stand-in physics is %.0f ms behind real time%s (the machine is overloaded)",
                        lag * 1e3, "; dropping the backlog" if resync else "")

    def _render_loop(self) -> None:
        """Decides what to draw and when; the drawing itself happens in the render process (render_process.py)."""
        period = 1.0 / self.camera_fps
        next_frame = 0.0
        next_face_tick = 0.0
        drawn_talking = False
        renderer: RenderProcess | None = None

        def state() -> tuple[tuple, tuple[float, float, float]]:
            with self._lock:
                qpos, qvel, sim_time = self.data.qpos.copy(), self.data.qvel.copy(), self.data.time
                stamps = (self.clock.monotonic(), self.clock.time(), sim_time)
            return (qpos, qvel, sim_time), stamps

        try:
            renderer = self._renderer = RenderProcess(self.model, self.camera_width, self.camera_height,
                                                      nice=self.render_nice, ring=self._ring,
                                                      reuse_unchanged=self.clock.simulated)
            self._render_ready.set()
            while not self._stop.is_set():
                with self._render_cond:
                    now = self.clock.monotonic()
                    voice = self._voice[0] if now - self._voice[1] < self.VOICE_HOLD_S else None
                    talking = now < self._talking_until or self._emotion == "talking" or voice is not None
                    face_due = (self._face_applied < self._face_version or (talking and now >= next_face_tick)
                                or (drawn_talking and not talking))  # speech ended: back to the still face
                    camera_due = self._camera_subscribers > 0 and now >= next_frame and not self.clock.simulated
                    requests = list(self._frame_requests)
                    self._frame_requests.clear()
                    if not (face_due or camera_due or self._snapshots or requests):
                        waits = [next_face_tick - now if talking else 1.0]
                        if self._camera_subscribers > 0:
                            waits.append(next_frame - now)
                        if now < self._talking_until:
                            waits.append(self._talking_until - now)
                        self._render_cond.wait(max(0.0005, min(waits if not self.clock.simulated else [0.05])))
                        continue
                    emotion, version = self._emotion, self._face_version
                    snapshots = list(self._snapshots)
                    self._snapshots.clear()
                if face_due:
                    face = renderer.face(emotion, now if talking else None, voice)
                    drawn_talking = talking
                    next_face_tick = now + 1.0 / self.FACE_ANIMATION_HZ
                    with self._render_cond:
                        self._face_image = face
                        self._face_applied = max(self._face_applied, version)
                        self._render_cond.notify_all()
                for camera, w, h, fut in snapshots:
                    try:
                        fut.set_result(renderer.snapshot(state()[0], camera, w, h))
                    except RenderProcessError as exc:
                        fut.set_exception(RuntimeError(f"the stand-in's renderer died: {exc}"))
                        raise
                    except Exception as exc:  # the caller gets the error, the renderer lives on
                        fut.set_exception(exc)
                for i, (state, stamps, fut) in enumerate(requests):
                    try:
                        self._render_frame(renderer, state, stamps)
                    except BaseException as exc:
                        for *_, waiting in requests[i:]:
                            waiting.set_exception(RuntimeError(f"the stand-in's renderer died: {exc}"))
                        raise
                    fut.set_result(None)
                if camera_due:
                    next_frame = max(next_frame + period, now) if next_frame else now + period
                    self._render_frame(renderer, *state())
        except RenderProcessError as exc:
            self._render_error = exc
            if self._render_ready.is_set() and not self._stop.is_set():  # the camera closes, the robot goes on
                log.error("%s; the head camera is closed (the robot keeps holding and moving as commanded)", exc)
        except BaseException as exc:
            self._render_error = exc
            log.exception("stand-in render thread died")
        finally:
            self._render_ready.set()
            with self._render_cond:
                for *_, fut in [*self._snapshots, *self._frame_requests]:
                    fut.set_exception(RuntimeError("the stand-in is closed" if self._stop.is_set() else
                                                   f"the stand-in's renderer died: {self._render_error}"))
                self._snapshots.clear()
                self._frame_requests.clear()
                self._render_cond.notify_all()
            with self._frame_cond:
                self._frame_cond.notify_all()
                closed_listeners = self._camera_closed_listeners
            if renderer is not None:
                renderer.close(self.RENDER_EXIT_S)
            self._ring.close()
            for callback in closed_listeners:
                try:
                    callback()
                except Exception:
                    log.exception("a camera-closed listener failed")

    def _render_frame(self, renderer: RenderProcess, state: tuple, stamps: tuple[float, float, float]) -> None:
        t_mono, t_wall, sim_time = stamps
        seq = self._seq + 1
        quality = self.jpeg_quality if self._jpeg_subscribers > 0 else None
        try:
            jpeg, width, height, render_ms, encode_ms = renderer.frame(state, quality, seq)
        except RenderProcessError:
            raise
        except RuntimeError as exc:
            log.error("a camera frame failed: %s", exc)
            return
        self._seq = seq
        frame = CameraFrame(jpeg, width, height, seq, t_mono, t_wall, sim_time, render_ms, encode_ms, ring=self._ring)
        with self._frame_cond:
            self._frame = frame
            self._frame_cond.notify_all()
            listeners = self._frame_listeners
        for callback in listeners:
            try:
                callback(frame)
            except Exception:
                log.exception("a camera frame listener failed")
