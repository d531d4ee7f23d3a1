"""The stand-in's renderer in a process of its own, at a lower CPU priority than the server.

Why a process: on a 2-core machine without a GPU, Mesa's llvmpipe renders the head camera (by default with every
core it finds; the worker asks it for one, see `serve`), and the JPEG encoding and the face drawing come on top.
In the server's process that work competes with the asyncio loop that carries the operator's poses; lowering the
render thread's priority there would let it be preempted while it holds the GIL (the loop then waits on a starved
thread). In its own process, at nice `RenderProcess.NICE` (its llvmpipe threads inherit it), the kernel gives the
server's threads the CPU first and the two share no GIL. bench/media.py's control rows measure the effect.

The worker is a request/reply server over a socket pair (the `worker_process` package: started with
subprocess, it exits when its socket closes, so it cannot outlive the server): the stand-in's render thread sends
the joint state and asks for a camera frame, a snapshot (RGB) or a face (drawn and uploaded as the screen's
texture); the worker answers each in order. A camera frame is drawn straight into a slot of the stand-in's frame
ring (worker_process/frame_ring.py: shared memory, read there by the video encoder process), and compressed to
JPEG here only when asked (someone watches the JPEG topic or records it): once per frame, never on the server's
event loop. It holds no state the server needs: if it dies, the camera closes and
the robot goes on (see StandIn).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from worker_process import WorkerDied, WorkerProcess, accept, answer
from worker_process.frame_ring import FrameRing

ROOT = Path(__file__).resolve().parent.parent  # the directory that holds the `sim` package
BOOT = "import sys; sys.path.insert(0, sys.argv[1]); from sim.render_process import serve; serve(int(sys.argv[2]))"


class RenderProcessError(WorkerDied):
    """The render process died, hung or could not start."""


class RenderProcess(WorkerProcess):
    """Parent side. Not thread-safe: one thread (the stand-in's render thread) makes every call."""

    NAME = "the stand-in's render process"
    NICE = 10  # added to the worker's niceness: the server's loop and physics threads win the CPU
    START_TIMEOUT_S = 60.0  # importing MuJoCo and creating a GL context, on a loaded machine
    REPLY_TIMEOUT_S = 30.0  # a frame takes milliseconds: a worker silent this long is hung
    Died = RenderProcessError

    def __init__(self, model: Any, width: int, height: int, *, nice: int = NICE, ring: FrameRing | None = None,
                 reuse_unchanged: bool = False) -> None:
        """`ring`: where camera frames go (of width x height; it must stay open while this process starts).
        `reuse_unchanged`: a camera frame whose view holds what the last one held is that frame again, not drawn
        (`VisibleScene`; render_ms 0)."""
        spec = None if ring is None else ring.spec()
        super().__init__(BOOT, [str(ROOT)], nice, (model, int(width), int(height), spec, bool(reuse_unchanged)),
                         pass_fds=() if ring is None else (ring.fd,))

    def frame(self, state: tuple, quality: int | None, seq: int = 0) -> tuple[bytes, int, int, float, float]:
        """The head camera at the given joint state, drawn into the ring's slot for frame `seq` (when there is a
        ring and seq > 0), and as a JPEG when `quality` is given (b"" otherwise): (jpeg, width, height,
        render_ms, encode_ms); render_ms is 0 for a frame reused (`reuse_unchanged`)."""
        return self.call(("frame", state, quality, seq))

    def snapshot(self, state: tuple, camera: str, width: int, height: int) -> np.ndarray:
        return self.call(("snapshot", state, camera, width, height))

    def face(self, emotion: str, talking_phase: float | None, voice_level: float | None) -> np.ndarray:
        """Draw the face, make it the screen's texture; returns the image drawn (RGB)."""
        return self.call(("face", emotion, talking_phase, voice_level))


# ---- the worker ----------------------------------------------------------------------------------------------
def serve(fd: int) -> None:
    """Worker entry point: answer requests until the socket closes."""
    conn, (model, width, height, ring, reuse) = accept(fd)  # the niceness first: llvmpipe's threads inherit it
    # Mesa's llvmpipe renders with a thread per core by default, and its threads wait for each other: on 2 cores
    # that takes both at every frame, and the loop's poses wait whatever their priority. In this one thread the
    # render leaves a core free (bench/media.py's control rows, 6 rounds pooled: pose round trip p99 with 5
    # viewers 1.22x of none, against 1.77x with a thread per core).
    # A GPU driver ignores it; a value set by the user is kept.
    os.environ.setdefault("LP_NUM_THREADS", "0")
    try:
        worker = _Worker(model, width, height, ring, reuse)
    except Exception as exc:
        conn.send((False, f"the renderer did not start ({exc!r}); MuJoCo needs MUJOCO_GL=egl (or osmesa) and a "
                          "working libEGL on a headless machine"))
        return
    try:
        answer(conn, lambda request: worker.handle(*request))
    finally:
        worker.close()


class _Worker:
    def __init__(self, model: Any, width: int, height: int, ring: tuple | None, reuse: bool = False) -> None:
        import mujoco

        from robot_models.mjcf import FACE_TEXTURE

        self.mujoco = mujoco
        self.model = m = model
        self.data = mujoco.MjData(m)
        self.width, self.height = width, height
        self.tex_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXTURE, FACE_TEXTURE)
        self.tex_w, self.tex_h = int(m.tex_width[self.tex_id]), int(m.tex_height[self.tex_id])
        start = int(m.tex_adr[self.tex_id])
        self.tex_slice = slice(start, start + self.tex_w * self.tex_h * int(m.tex_nchannel[self.tex_id]))
        self.renderers: dict[tuple[int, int], Any] = {}
        self.renderer(width, height)
        self.ring = None if ring is None else FrameRing.attach(ring)
        self.visible = VisibleScene.of(m, width, height) if reuse else None
        self.last: tuple[bytes, np.ndarray, dict[int, bytes]] | None = None  # (view key, pixels, JPEG by quality)

    def renderer(self, w: int, h: int) -> Any:
        r = self.renderers.get((w, h))
        if r is None:
            r = self.renderers[(w, h)] = self.mujoco.Renderer(self.model, h, w)
            self.mujoco.mjr_uploadTexture(self.model, r._mjr_context, self.tex_id)
        return r

    def handle(self, kind: str, *args: Any) -> Any:
        return getattr(self, f"do_{kind}")(*args)

    def set_state(self, state: tuple) -> None:
        qpos, qvel, t = state
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        self.data.time = t
        self.mujoco.mj_forward(self.model, self.data)

    def do_frame(self, state: tuple, quality: int | None, seq: int) -> tuple[bytes, int, int, float, float]:
        import cv2

        from robot_models.mjcf import HEAD_CAMERA

        self.set_state(state)
        r = self.renderer(self.width, self.height)
        key = None if self.visible is None else self.visible.key(self.data)
        out = self.ring.begin(seq) if self.ring is not None and seq > 0 else None
        c0 = time.perf_counter()
        reused = self.last is not None and key == self.last[0]  # the same view: the same picture
        if reused:
            rgb = self.last[1]
            if out is not None:
                out[...] = rgb
        else:
            r.update_scene(self.data, camera=HEAD_CAMERA)
            rgb = r.render(out=out)  # straight into shared memory when there is a ring: no copy
            self.last = None if key is None else (key, rgb.copy(), {})
        if out is not None:
            self.ring.commit(seq)
        c1 = c0 if reused else time.perf_counter()
        jpeg = b""
        if quality is not None:
            jpeg = self.last[2].get(quality, b"") if self.last is not None else b""
            if not jpeg:
                ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                                       [cv2.IMWRITE_JPEG_QUALITY, quality])
                if not ok:
                    raise RuntimeError("JPEG encoding of a camera frame failed")
                jpeg = buf.tobytes()
                if self.last is not None:
                    self.last[2][quality] = jpeg
        c2 = time.perf_counter()
        return jpeg, rgb.shape[1], rgb.shape[0], (c1 - c0) * 1e3, (c2 - c1) * 1e3

    def do_snapshot(self, state: tuple, camera: str, width: int, height: int) -> np.ndarray:
        self.set_state(state)
        r = self.renderer(width, height)
        r.update_scene(self.data, camera=camera)
        return r.render().copy()

    def do_face(self, emotion: str, talking_phase: float | None, voice_level: float | None) -> np.ndarray:
        from .face import draw_face

        face = draw_face(emotion, self.tex_w, self.tex_h, talking_phase=talking_phase, voice_level=voice_level)
        self.model.tex_data[self.tex_slice] = face.reshape(-1)
        self.last = None  # the screen may be in view
        for r in self.renderers.values():
            self.mujoco.mjr_uploadTexture(self.model, r._mjr_context, self.tex_id)
        return face

    def close(self) -> None:
        for r in self.renderers.values():
            r.close()
        if self.ring is not None:
            self.ring.close()


class VisibleScene:
    """What a camera can show, as bytes: two equal keys mean the same picture.

    The key holds the camera's pose and, for each geom whose bounding sphere may reach into the camera's view
    (a frustum widened by a margin, so the test errs toward "in view"), its index, pose, size and colour; geoms
    without a bound (planes) are always in it. A geom that leaves the view was in the last key, one that enters
    is in this one, so any change in view changes the key. That holds only where a geom out of view changes no
    pixel: without shadows, reflections, lights on moving bodies, or sites and tendons drawn (`of` returns None
    otherwise), with a face texture that has not changed (the worker forgets its last frame when it uploads one).
    """

    MARGIN = 1.25  # on the frustum's half-angles' tangents and on the bounding radii
    # Poses are compared to a nanometre (a millionth of a pixel at this camera's scale): a servo holding still
    # leaves a few units in the last place (1e-38 m seen) that no pixel shows.
    DECIMALS = 9

    def __init__(self, model: Any, camera: int, tan_x: float, tan_y: float, znear: float) -> None:
        self.camera, self.tan_x, self.tan_y, self.znear = camera, tan_x, tan_y, znear
        self.rbound = model.geom_rbound * self.MARGIN
        self.unbounded = model.geom_rbound <= 0
        self.rgba, self.size = model.geom_rgba, model.geom_size
        self.nx, self.ny = np.hypot(1.0, tan_x), np.hypot(1.0, tan_y)

    @classmethod
    def of(cls, model: Any, width: int, height: int) -> VisibleScene | None:
        import mujoco

        from robot_models.mjcf import HEAD_CAMERA

        if (model.light_castshadow.any() or (model.light_bodyid != 0).any()  # a light that moves lights anew
                or (model.nmat and model.mat_reflectance.max() > 0) or model.ntendon
                or model.nskin or getattr(model, "nflex", 0) or (model.nsite and (model.site_group < 3).any())):
            return None
        cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, HEAD_CAMERA)
        ty = np.tan(np.radians(model.cam_fovy[cam]) / 2)
        tx = ty * width / height
        sensor, intr = model.cam_sensorsize[cam], model.cam_intrinsic[cam]
        if sensor[0] > 0 and intr[0] > 0 and intr[1] > 0:  # intrinsics, with the principal point's offset
            tx = max(tx, (sensor[0] / 2 + abs(intr[2])) / intr[0])
            ty = max(ty, (sensor[1] / 2 + abs(intr[3])) / intr[1])
        return cls(model, cam, tx * cls.MARGIN, ty * cls.MARGIN, model.vis.map.znear * model.stat.extent)

    def key(self, data: Any) -> bytes:
        pos, rot = data.cam_xpos[self.camera], data.cam_xmat[self.camera].reshape(3, 3)
        local = (data.geom_xpos - pos) @ rot  # camera frame: x right, y up, looking along -z
        x, y, depth = local[:, 0], local[:, 1], -local[:, 2]
        r = self.rbound
        near = depth + r > self.znear
        sides = ((np.abs(x) - self.tan_x * depth) / self.nx < r) & ((np.abs(y) - self.tan_y * depth) / self.ny < r)
        seen = np.flatnonzero((near & sides) | self.unbounded)
        parts = (pos, rot, data.geom_xpos[seen], data.geom_xmat[seen], self.size[seen], self.rgba[seen])
        return seen.tobytes() + b"".join((np.round(p, self.DECIMALS) + 0.0).tobytes() for p in parts)  # no -0.0
