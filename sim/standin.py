"""The stand-in robot: QTrobot in a MuJoCo classroom, its joints, face screen and head camera.

StandIn puts together the rooms that do each job:
- physics.py: MuJoCo stepping with rate-limited position servos and motor modes (thermal.py: modelled motor
  temperatures), in a thread at real-time factor 1;
- camera.py: the render thread deciding what to draw and when (the face texture from expression.py's state, the
  head camera only while someone watches, snapshots), drawn by the render process (render_process.py: the OpenGL
  context, llvmpipe, JPEG, the face) at a lower CPU priority and with its own GIL, so the server's event loop is
  not delayed by it. If that process dies, the camera closes while the physics goes on: the robot holds;
- on a simulated clock (simclock; replays and studies at `--speed max`) there is no physics thread: the stand-in
  attaches to the clock, which steps the physics and asks for camera frames (at camera_fps in simulated time, while
  someone watches) in its loop's thread as it advances (next_due, advance_to), in lock-step with simulated time.
Callers (the asyncio loop, tests) only take short locks: every public method returns in microseconds, except
snapshot() and the wait_* helpers, which block by design and say so.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Mapping

import mujoco
import numpy as np

from robot_models import RobotModel, load_qtrobot
from robot_models.mjcf import HEAD_CAMERA
from robot_models.types import CameraFrame, MotorMode
from simclock import WALL, Clock
from worker_process.frame_ring import FrameRing

from .camera import Camera
from .physics import JointSnapshot, Physics, PhysicsStats
from .pupils import AWAY_DEG, neck_joint, pupil
from .render_process import RenderProcess
from .scene import ClassroomScene, build_classroom

log = logging.getLogger(__name__)

__all__ = ["CameraFrame", "JointSnapshot", "MotorMode", "PhysicsStats", "StandIn"]


class StandIn:
    """QTrobot in a MuJoCo classroom, running in real time in background threads.

    Use as a context manager or call close(). Joint names, limits and caps come from `robot`.
    antialias defaults to 0 (no MSAA): without a GPU, 4x MSAA triples the render time (bench/standin.py:
    about 27 ms against 9 ms a 640x480 frame on 2 loaded cores) and costs the 30 fps target.
    render_nice: how much lower the render process's CPU priority is than this process's (RenderProcess.NICE);
    none on a simulated clock, where the clock waits for each frame (a niced renderer starves on a busy machine).
    """

    # What close() waits for the render thread: one call in flight (the worker is killed past its reply timeout),
    # then the worker's exit; the physics thread wakes on the stop event at once.
    STOP_TIMEOUT_S = RenderProcess.REPLY_TIMEOUT_S + Camera.RENDER_EXIT_S + 5.0

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
        self.scene = scene or build_classroom(
            self.robot, shadows=shadows, antialias=antialias,
            offscreen_size=(max(1280, self.camera_width), max(720, self.camera_height)))
        self.model = m = self.scene.model
        if m.vis.global_.offwidth < self.camera_width or m.vis.global_.offheight < self.camera_height:
            raise ValueError(f"camera size {self.camera_width}x{self.camera_height} exceeds the scene's offscreen "
                             f"buffer {m.vis.global_.offwidth}x{m.vis.global_.offheight}; build the scene with a "
                             "larger offscreen_size")
        self.physics = Physics(self.robot, m, ambient_temperature_c=ambient_temperature_c)
        self.names, self.dt = self.physics.names, self.physics.dt
        self._stop = threading.Event()
        self.camera = Camera(self.physics, m, clock, self._stop, width=self.camera_width, height=self.camera_height,
                             fps=float(camera_fps), jpeg_quality=int(jpeg_quality),
                             render_nice=0 if clock.simulated else int(render_nice), initial_emotion=initial_emotion)
        self._physics_thread = threading.Thread(target=self.physics.run, args=(self._stop,), name="standin-physics",
                                                daemon=True)
        self._render_thread = self.camera.thread
        # The renderer starts first: starting its process and a GL context costs a second of CPU that would
        # otherwise make the physics loop start behind real time.
        if not self.camera.start():
            self.close()
            raise RuntimeError(f"the stand-in's renderer did not start ({self.camera.error!r}); MuJoCo needs "
                               "MUJOCO_GL=egl (or osmesa) and a working libEGL on a headless machine")
        if clock.simulated:
            clock.attach(self)  # type: ignore[attr-defined]
        else:
            self._physics_thread.start()

    # ----------------------------------------------------------------------------------------------- joints
    def set_targets(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Set joint goals in degrees; returns the goals applied after clamping to the joint limits.
        Joints whose motor is not ON ignore the command and are left out of the result."""
        return self.physics.set_targets(targets)

    def pupil_looks(self, name: str, at_robot: bool) -> None:
        """Turn a pupil's head towards the robot or away from it: the head camera's next frame shows it."""
        self.physics.set_scene_joint(neck_joint(pupil(name).name), 0.0 if at_robot else AWAY_DEG)

    def set_velocity_caps(self, caps: Mapping[str, float]) -> None:
        """Change velocity caps (deg/s) at run time; validated by RobotModel.with_velocity_caps."""
        self.physics.set_velocity_caps(caps)
        self.robot = self.physics.robot

    def set_motor_mode(self, joints: Iterable[str], mode: MotorMode | int) -> None:
        """Switch joints between ON, OFF (limp) and BRAKE (hold here). Going ON holds the current position,
        so a stale goal cannot make the joint jump."""
        self.physics.set_motor_mode(joints, mode)

    def joint_state(self) -> JointSnapshot:
        """The joints as of the physics thread's last batch (at most Physics.STEPS_PER_LOCK steps old), with the
        goals as set; on a simulated clock, as of the clock's time; without a physics thread, as of now."""
        if self._physics_thread.is_alive() or self.clock.simulated:
            q, v, sp, f, (t,) = self.physics.state
        else:
            with self.physics.lock:
                q, v, sp, f, (t,) = self.physics.capture()
        goal, modes = self.physics.goals()
        return JointSnapshot(self.names, q, v, goal, sp, f, modes, self.clock.monotonic(), self.clock.time(), t)

    def joint_positions(self) -> dict[str, float]:
        s = self.joint_state()
        return dict(zip(s.names, s.positions))

    def targets(self) -> dict[str, float]:
        return self.physics.targets()

    def motor_temperatures(self) -> dict[str, float]:
        """Modelled motor temperatures, degrees Celsius (thermal.py)."""
        return self.physics.temperatures()

    def physics_stats(self) -> PhysicsStats:
        return self.physics.stats()

    # ------------------------------------------------------------------------------------------------- face
    def set_emotion(self, name: str) -> None:
        """Show an emotion ("happy" or "QT/happy"); the render thread redraws the face texture."""
        self.camera.face.set_emotion(name)

    @property
    def emotion(self) -> str:
        return self.camera.face.emotion

    def speak(self, duration_s: float) -> None:
        """Animate the talking mouth for duration_s seconds from now (returns at once)."""
        self.camera.face.speak(duration_s)

    def is_talking(self) -> bool:
        return self.camera.face.is_talking()

    def set_voice_level(self, level: float) -> None:
        """The operator's voice, as the robot plays it (0..1): the mouth opens with it (returns at once)."""
        self.camera.face.set_voice_level(level)

    @property
    def voice_level(self) -> float:
        """The voice level the face shows now (0 once the voice has stopped for Expression.VOICE_HOLD_S)."""
        return self.camera.face.voice_level()

    def face_image(self) -> np.ndarray | None:
        """A copy of the face texture as last uploaded (RGB), or None before the first upload."""
        return self.camera.face.copy_image()

    def face_image_with_voice(self) -> tuple[np.ndarray | None, float | None]:
        """face_image() and the operator's voice level it was drawn with (None: drawn with no voice), for telling
        a face drawn while the voice sounds from one drawn after it stopped."""
        return self.camera.face.copy_image_with_voice()

    def wait_face(self, timeout: float = 2.0) -> bool:
        """Block until the render thread has applied every face change requested so far."""
        return self.camera.face.wait_applied(timeout, self._stop)

    # ----------------------------------------------------------------------------------------------- camera
    def start_camera(self, jpeg: bool = True) -> None:
        """Count one more viewer; frames are rendered while at least one is counted, and compressed to JPEG while
        at least one counted with `jpeg` (the others read the frame ring: `frame_ring`)."""
        self.camera.add_viewer(jpeg)

    def stop_camera(self, jpeg: bool = True) -> None:
        self.camera.remove_viewer(jpeg)

    def wait_camera_stopped(self, timeout: float = 30.0) -> bool:
        """Block until nobody watches and the render thread has acknowledged it: a frame it had in flight has
        been handed out, and none comes until the camera is started again (for tests and tools; not for the event
        loop). False on timeout."""
        return self.camera.wait_stopped(timeout)

    @property
    def frame_ring(self) -> FrameRing:
        """The shared memory the camera's raw frames go to (closed once the renderer has stopped)."""
        return self.camera.ring

    @property
    def camera_subscribers(self) -> int:
        return self.camera.subscribers

    def add_frame_listener(self, callback: Callable[[CameraFrame], None]) -> None:
        """Call `callback(frame)` from the render thread for every new frame; it must be quick and thread-safe
        (an asyncio user hands off with loop.call_soon_threadsafe)."""
        self.camera.add_frame_listener(callback)

    def remove_frame_listener(self, callback: Callable[[CameraFrame], None]) -> None:
        self.camera.remove_frame_listener(callback)

    def add_camera_closed_listener(self, callback: Callable[[], None]) -> None:
        """Call `callback()` (from the render thread) once the camera has closed for good: on close(), or when the
        render process died. Quick and thread-safe, as a frame listener."""
        self.camera.add_closed_listener(callback)

    @property
    def render_error(self) -> BaseException | None:
        """Why the renderer stopped (its process died, or it did not start), or None while it works."""
        return self.camera.error

    @property
    def render_pid(self) -> int | None:
        """The render process's id (for tools and tests), or None before it started."""
        return None if self.camera.renderer is None else self.camera.renderer.pid

    def latest_frame(self) -> CameraFrame | None:
        return self.camera.frame

    def wait_frame(self, after_seq: int = 0, timeout: float = 2.0) -> CameraFrame | None:
        """Block until a frame newer than after_seq exists (for tests and tools; not for the event loop)."""
        return self.camera.wait_frame(after_seq, timeout)

    def snapshot(self, camera: str = HEAD_CAMERA, width: int | None = None, height: int | None = None,
                 timeout: float = 5.0) -> np.ndarray:
        """Render one RGB image from a named camera of the scene. Blocks up to `timeout` (run it in a thread
        when called from asyncio)."""
        if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            names = [mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(self.model.ncam)]
            raise KeyError(f"no camera {camera!r} in the scene; cameras: {names}")
        return self.camera.snapshot(camera, int(width or self.camera_width), int(height or self.camera_height),
                                    timeout)

    # ---------------------------------------------------------------------- on a simulated clock (simclock)
    def next_due(self) -> float:
        """When the camera's next frame is due in simulated time (none while nobody watches)."""
        return self.camera.next_due()

    def advance_to(self, t: float) -> None:
        """The clock's loop thread: step the physics to simulated time t; draw the camera frame due at t."""
        if self._stop.is_set():
            return
        self.physics.step_to(t)
        self.camera.request_frame(t)

    # -------------------------------------------------------------------------------------------- lifecycle
    def close(self) -> None:
        """Stop both threads (promptly: they wake on the stop event) and the render process."""
        self._stop.set()
        if self.clock.simulated:
            self.clock.detach(self)  # type: ignore[attr-defined]
        self.camera.wake()
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
