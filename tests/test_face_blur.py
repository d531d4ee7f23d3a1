"""`serve --blur-faces` on the stand-in, whose pupils sit in the head camera's view: what is recorded and what a
spectator sees (the camera topic, the WebRTC video) has their faces blurred; the operator and the supervisor see them.
Whether a face is there is the server's own detector's answer (tests/test_faces.py holds its recall on the pupils)."""

from __future__ import annotations

import base64
from typing import Any

import cv2
import numpy as np
import pytest

from client_protocol import names
from client_protocol.registry import TypeRegistry
from testbed.media_client import MediaPeer, Rosbridge
from testbed.waiting import until
from vr_teleop_server.core.bus import Bus
from vr_teleop_server.features.face_blur import FaceBlur
from vr_teleop_server.features.faces import FaceBox, FaceDetector
from vr_teleop_server.recording.format import read_recording
from worker_process.face_blur import MARGIN, WHOLE_FRAME

TOKENS = {"operator_token": "op-token", "supervisor_token": "sup-token", "spectator_token": "spec-token"}
CAMERA = "sensor_msgs/CompressedImage"


@pytest.fixture(scope="module")
def detector() -> FaceDetector:
    return FaceDetector()


@pytest.fixture(scope="module")
def blurring(module_servers, tmp_path_factory):
    """One server for the module: the stand-in, its pupils quiet, recording two camera frames a second."""
    path = tmp_path_factory.mktemp("blur") / "session.mcap"
    server = module_servers(backend="sim", bystander_interval=0, blur_faces=True, record=path, **TOKENS)
    return server, path


def decode(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)


def sharpness(image: np.ndarray, box: FaceBox) -> float:
    """High-frequency energy in a face's box: the variance of the Laplacian (a blur takes it away)."""
    patch = cv2.cvtColor(image[box.y:box.y + box.height, box.x:box.x + box.width], cv2.COLOR_BGR2GRAY)
    return float(cv2.Laplacian(patch, cv2.CV_64F).var())


def near(found: list[FaceBox], box: FaceBox) -> bool:
    """A face found where `box` is (its centre within the box)."""
    return any(abs(f.x + f.width / 2 - (box.x + box.width / 2)) <= box.width / 2
               and abs(f.y + f.height / 2 - (box.y + box.height / 2)) <= box.height / 2 for f in found)


def outside(image: np.ndarray, boxes: list[FaceBox]) -> np.ndarray:
    """A mask of the pixels outside every box grown by the blur's margin (and a little more for JPEG's blocks)."""
    mask = np.ones(image.shape[:2], bool)
    for b in boxes:
        m = MARGIN + 0.2
        mask[max(0, int(b.y - m * b.height)):int(b.y + b.height * (1 + m)) + 8,
             max(0, int(b.x - m * b.width)):int(b.x + b.width * (1 + m)) + 8] = False
    return mask


@pytest.mark.slow  # three camera streams, every frame searched for faces
async def test_a_spectators_camera_topic_is_blurred_and_the_operators_and_supervisors_is_not(blurring, detector):
    server, _ = blurring
    clients = {role: await Rosbridge.open(server.url, token=token)
               for role, token in (("operator", "op-token"), ("supervisor", "sup-token"), ("spectator", "spec-token"))}
    try:
        queues = {role: await ros.subscribe(names.CAMERA_TOPIC, CAMERA, queue_length=5)
                  for role, ros in clients.items()}
        frames: dict[str, dict[int, bytes]] = {role: {} for role in clients}
        found: dict[str, Any] = {}

        def drain() -> None:
            for role, queue in queues.items():
                while not queue.empty():
                    msg = queue.get_nowait()
                    kept = frames[role]
                    kept[msg["header"]["seq"]] = base64.b64decode(msg["data"])
                    while len(kept) > 60:
                        del kept[min(kept)]

        def compared() -> bool:
            """A frame both the operator and the spectator got, with faces in the operator's and none where they
            are in the spectator's, which is otherwise the same picture (the faces blurred, not the frame)."""
            drain()
            for seq in sorted(set(frames["operator"]) & set(frames["spectator"]), reverse=True)[:2]:
                raw_jpeg = frames["operator"].pop(seq)
                raw, blurred = decode(raw_jpeg), decode(frames["spectator"].pop(seq))
                faces = detector.detect(raw)
                if not faces:
                    continue
                mask = outside(raw, faces)
                rest = float(np.abs(raw.astype(int) - blurred.astype(int))[mask].mean())
                if rest > 4.0:  # blurred whole: detection had not run recently enough yet
                    continue
                found.update(seq=seq, faces=faces, raw_jpeg=raw_jpeg, raw=raw, blurred=blurred)
                return True
            return False

        assert await until(compared, 90), {role: len(f) for role, f in frames.items()}
        faces, raw, blurred = found["faces"], found["raw"], found["blurred"]
        assert not any(near(detector.detect(blurred), f) for f in faces), faces
        for face in faces:
            assert sharpness(blurred, face) < 0.2 * sharpness(raw, face), face
        # The supervisor got the operator's frame itself, faces and all.
        assert await until(lambda: (drain() or found["seq"] in frames["supervisor"]), 30)
        assert frames["supervisor"][found["seq"]] == found["raw_jpeg"]
    finally:
        for ros in clients.values():
            await ros.close()


@pytest.mark.slow  # two WebRTC peers, every frame searched for faces
async def test_a_spectators_webrtc_video_is_blurred_and_the_operators_is_not(blurring, detector):
    server, _ = blurring
    viewers: dict[str, tuple[Rosbridge, MediaPeer]] = {}
    try:
        for role, token in (("operator", "op-token"), ("spectator", "spec-token")):
            ros = await Rosbridge.open(server.url, token=token)
            peer = MediaPeer(audio=False)
            viewers[role] = ros, peer
            reply = await peer.negotiate(ros)
            assert reply["values"]["success"], reply
        for _ros, peer in viewers.values():
            await peer.wait_video(3, timeout=60)
        seen: dict[str, Any] = {}

        def compared() -> bool:
            """The operator's newest frame has faces; the spectator's newest has none there and is not blurred
            whole (the scene holds still: the head is not moved, the pupils are quiet)."""
            op_frames, spec_frames = viewers["operator"][1].frames, viewers["spectator"][1].frames
            if not op_frames or not spec_frames:
                return False
            raw = op_frames[-1][1].to_ndarray(format="bgr24")
            blurred = spec_frames[-1][1].to_ndarray(format="bgr24")
            faces = detector.detect(raw)
            if not faces or raw.shape != blurred.shape:
                return False
            mask = outside(raw, faces)
            if cv2.Laplacian(cv2.cvtColor(blurred, cv2.COLOR_BGR2GRAY), cv2.CV_64F)[mask].var() < \
                    0.5 * cv2.Laplacian(cv2.cvtColor(raw, cv2.COLOR_BGR2GRAY), cv2.CV_64F)[mask].var():
                return False  # blurred whole: no recent detection yet
            seen.update(faces=faces, raw=raw, blurred=blurred)
            return True

        assert await until(compared, 90)
        assert not any(near(detector.detect(seen["blurred"]), f) for f in seen["faces"]), seen["faces"]
        for face in seen["faces"]:
            assert sharpness(seen["blurred"], face) < 0.2 * sharpness(seen["raw"], face), face
        media = server.server.media
        assert server.call(lambda: (media.video.watching, media.blurred_video.watching)) == (1, 1)
    finally:
        for ros, peer in viewers.values():
            await peer.close()
            await ros.close()


async def test_the_recording_holds_blurred_frames_and_which_had_a_detection_of_their_own(blurring, detector):
    server, path = blurring
    ros = await Rosbridge.open(server.url, token="op-token")  # the operator watches: the camera runs, raw for them

    def recorded() -> tuple[list[Any], list[Any], set[int]]:
        if not path.stat().st_size:  # the writer's first block has not reached the file yet
            return [], [], set()
        messages = list(read_recording(path))
        camera = [m for m in messages if m.topic == names.CAMERA_TOPIC]
        notes = [m for m in messages if m.topic == names.FACE_BLUR_TOPIC]
        searched = {m.data["frame_seq"] for m in messages if m.topic == names.FACES_TOPIC}
        return camera, notes, searched

    try:
        await ros.subscribe(names.CAMERA_TOPIC, CAMERA, queue_length=1, throttle_rate=1000)
        assert await until(lambda: sum(bool(n.data["faces"]) for n in recorded()[1]) >= 3, 90, blocking=True)
    finally:
        await ros.close()
    camera, notes, searched = recorded()
    by_seq = {m.data["header"]["seq"]: m for m in camera}
    checked = 0
    for note in notes:
        blur = note.data
        frame = by_seq[blur["frame_seq"]]  # each note beside its frame, at the frame's time
        assert frame.time_ns == note.time_ns and blur["header"] == frame.data["header"]
        # what the note says of detection is what /perception/faces recorded (a search of this very frame may
        # also have ended after the frame was blurred with the boxes before)
        assert not blur["detected"] or blur["frame_seq"] in searched
        assert blur["whole_frame"] == (blur["detection_seq"] == 0)
        if blur["detection_seq"]:
            assert blur["detection_seq"] in searched and 0 <= blur["detection_age"] <= 1.0
        image = decode(base64.b64decode(frame.data["data"]))
        boxes = [FaceBox(f["x"], f["y"], f["width"], f["height"], f["confidence"]) for f in blur["faces"]]
        if boxes:
            found = detector.detect(image)
            assert not any(near(found, b) for b in boxes), (blur, found)
            checked += 1
    assert checked >= 3
    # and every frame has its note (but the newest, whose note a read of the file being written may not reach yet)
    assert {m.data["header"]["seq"] for m in camera} - {n.data["frame_seq"] for n in notes} <= {max(by_seq)}


class _Clock:
    """The blur's clock, moved by hand: the hold is a matter of seconds."""

    def __init__(self) -> None:
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now


async def test_a_face_one_search_missed_stays_blurred_for_the_hold_then_the_whole_frame_is() -> None:
    bus = Bus(TypeRegistry())
    clock = _Clock()
    blur = FaceBlur(bus, robot=None, clock=clock, hold_s=1.0)  # type: ignore[arg-type] (no camera: plans only)
    blur.start()
    try:
        first = blur.plan(1)
        assert first.regions == WHOLE_FRAME and not first.detected  # no search yet: nothing is trusted
        assert bus.topics[names.FACES_TOPIC].subscribers  # asking for a plan started detection

        def faces(seq: int, *boxes: tuple[int, int, int, int]) -> None:
            bus.publish(names.FACES_TOPIC, {"header": {"seq": seq}, "frame_seq": seq, "image_width": 640,
                                            "image_height": 480, "detector": "test",
                                            "faces": [{"x": x, "y": y, "width": w, "height": h, "confidence": 0.5}
                                                      for x, y, w, h in boxes]})

        faces(2, (10, 20, 30, 40), (200, 100, 30, 40))
        assert blur.plan(2).detected and set(blur.plan(2).regions) == {(10, 20, 30, 40), (200, 100, 30, 40)}
        clock.now += 0.5
        faces(3, (12, 20, 30, 40))  # the second face missed by this search
        plan = blur.plan(4)
        assert not plan.detected and plan.detection_seq == 3 and plan.detection_age == 0.0
        assert {(12, 20, 30, 40), (200, 100, 30, 40)} <= set(plan.regions)
        clock.now += 0.7  # past the first search's hold: its boxes go, the second search's stay
        assert set(blur.plan(5).regions) == {(12, 20, 30, 40)}
        clock.now += 0.5  # no search within the hold
        assert blur.plan(6).regions == WHOLE_FRAME
        # No frame asks for a plan any more: detection stops once its lease (LEASE_S) runs out, and what it found is
        # not trusted by the next run.
        assert await until(lambda: not bus.topics[names.FACES_TOPIC].subscribers, 30)
        faces(7, (12, 20, 30, 40))  # a search that ended after the blur stopped listening
        assert blur.plan(8).regions == WHOLE_FRAME and bus.topics[names.FACES_TOPIC].subscribers
    finally:
        await blur.stop()
    assert not bus.topics[names.FACES_TOPIC].subscribers

