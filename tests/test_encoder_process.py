"""The video encoder process on its own (media/encoder_process.py): frames in (JPEGs over its socket, or numbers
of frames in a frame ring), VP8 and H.264 out."""

from __future__ import annotations

from collections.abc import Iterator

import av
import cv2
import numpy as np
import psutil
import pytest

from test_frame_ring import holds_ring
from vr_teleop_server.media.encoder_process import REOPEN_INTERVAL_S, EncoderProcess, EncoderProcessError
from worker_process.frame_ring import FrameRing

BITRATE = 800_000


@pytest.fixture
def encoder() -> Iterator[EncoderProcess]:
    process = EncoderProcess(30.0)
    yield process
    process.close()


def jpeg(shift: int) -> bytes:
    """A 640x480 picture whose content moves with `shift`."""
    x = (np.arange(640)[None, :] + shift) % 256
    image = np.broadcast_to(x, (480, 640)).astype(np.uint8)
    ok, data = cv2.imencode(".jpg", cv2.merge([image, image[::-1], 255 - image]))
    assert ok
    return data.tobytes()


def decode(codec: str, chunks: list[bytes]) -> list[np.ndarray]:
    context = av.CodecContext.create({"VP8": "vp8", "H264": "h264"}[codec], "r")
    frames = []
    for chunk in chunks:
        frames += [f.to_ndarray(format="gray") for f in context.decode(av.Packet(chunk))]
    return frames


def test_each_codec_encodes_decodable_frames_starting_with_a_keyframe(encoder: EncoderProcess) -> None:
    chunks: dict[str, list[bytes]] = {"VP8": [], "H264": []}
    keys = []
    for i in range(5):
        result = encoder.encode(jpeg(8 * i), i * 3000, {"VP8": (False, BITRATE), "H264": (False, BITRATE)})
        for codec, (data, key, bitrate) in result.items():
            assert bitrate == BITRATE
            chunks[codec].append(data)
            keys.append((codec, i, key))
    assert ("VP8", 0, True) in keys and ("H264", 0, True) in keys  # a new encoder starts with a keyframe
    assert ("VP8", 1, False) in keys
    for codec, data in chunks.items():
        frames = decode(codec, data)
        assert len(frames) >= 4 and frames[0].shape == (480, 640), codec
        assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 5, f"{codec}: the picture did not move"


def test_a_frame_that_is_not_a_jpeg_or_a_codec_it_lacks_is_lost_alone(encoder: EncoderProcess) -> None:
    assert encoder.encode(b"not a jpeg", 0, {"VP8": (False, BITRATE)}) == {
        "VP8": "a camera frame of 10 bytes is not a JPEG; not encoded"}
    assert "no encoder for AV1" in encoder.encode(jpeg(0), 0, {"AV1": (False, BITRATE)})["AV1"]
    data, key, _ = encoder.encode(jpeg(0), 3000, {"VP8": (False, BITRATE)})["VP8"]
    assert key and decode("VP8", [data])


def test_a_keyframe_is_made_when_asked_and_the_bitrate_followed(encoder: EncoderProcess) -> None:
    encoder.encode(jpeg(0), 0, {"VP8": (False, BITRATE)})
    _, key, _ = encoder.encode(jpeg(1), 3000, {"VP8": (False, BITRATE)})["VP8"]
    assert not key
    _, key, _ = encoder.encode(jpeg(2), 6000, {"VP8": (True, BITRATE)})["VP8"]
    assert key
    # A target far from the current one rebuilds the encoder at it (starting with a keyframe), at most once a
    # second of the video (its frames' pts, at 90 kHz): within that second the encoder keeps its target, past it
    # the next frame is encoded at the new one.
    _, key, bitrate = encoder.encode(jpeg(3), 9000, {"VP8": (False, 200_000)})["VP8"]
    assert not key and bitrate == BITRATE
    _, key, bitrate = encoder.encode(jpeg(4), round(REOPEN_INTERVAL_S * 90000), {"VP8": (False, 200_000)})["VP8"]
    assert key and bitrate == 200_000


def test_a_dead_encoder_is_an_error_and_it_never_outlives_its_socket(encoder: EncoderProcess) -> None:
    worker = psutil.Process(encoder.pid)
    assert worker.nice() > psutil.Process().nice()
    worker.kill()
    with pytest.raises(EncoderProcessError, match="exited"):
        encoder.encode(jpeg(0), 0, {"VP8": (False, BITRATE)})
    other = EncoderProcess(30.0)
    other._conn.close()  # what the server's exit does: the worker reads the end of its socket and leaves
    assert other.process.wait(10) == 0


def test_frames_from_the_ring_are_encoded_without_a_jpeg_and_a_lapped_one_is_lost() -> None:
    """The render process draws into the frame ring; the encoder process maps it and reads frames by number."""
    ring = FrameRing.create(640, 480)
    writer = FrameRing.attach((ring.dup(), 640, 480, ring.slots))
    process = EncoderProcess(30.0, ring=ring)
    try:
        assert holds_ring(process.pid)
        chunks = []
        for seq in range(1, 6):
            writer.begin(seq)[:] = cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg(8 * seq), np.uint8),
                                                             cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            writer.commit(seq)
            data, key, _ = process.encode(seq, seq * 3000, {"VP8": (False, BITRATE)})["VP8"]
            assert key == (seq == 1)
            chunks.append(data)
        frames = decode("VP8", chunks)
        assert len(frames) == 5 and frames[0].shape == (480, 640)
        assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 5, "the picture did not move"
        writer.begin(5 + ring.slots)  # the writer came round to frame 5's slot
        assert process.encode(5, 6 * 3000, {"VP8": (False, BITRATE)}) == {}
        ring.close()  # the owner lets go; the encoder process keeps its own hold while it lives
        writer.commit(5 + ring.slots)
        assert process.encode(5 + ring.slots, 7 * 3000, {"VP8": (False, BITRATE)})["VP8"][0]
        with pytest.raises(EncoderProcessError, match="ring is closed"):
            EncoderProcess(30.0, ring=ring)
    finally:
        process.close()
        writer.close()
        ring.close()
    assert process.process.poll() is not None  # exited: its hold on the ring went with it


@pytest.mark.parametrize("codec", ["H264", "VP8"])
def test_the_encoders_hold_no_frame_back_and_make_no_b_frames(codec: str) -> None:
    """Issue 36: the encoders stay in their zero-latency settings (encoder_options: x264's ultrafast preset with
    tune zerolatency, libvpx realtime with lag-in-frames 0): each frame in comes out at once, before the next is
    given (no lookahead, no frame threads), in presentation order (no B-frames: a decoder reorders nothing), and
    the H.264 is constrained baseline, the profile the page asks for (profile-level-id 42e01f)."""
    from vr_teleop_server.media.encoder_process import encoder_options, open_encoder

    context = open_encoder(av, codec, 640, 480, BITRATE, 30.0, encoder_options(codec, BITRATE))
    decoder = av.CodecContext.create({"VP8": "vp8", "H264": "h264"}[codec], "r")
    types = []
    for i in range(12):
        image = av.VideoFrame.from_ndarray(cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg(8 * i), np.uint8),
                                                                     cv2.IMREAD_COLOR), cv2.COLOR_BGR2YUV_I420),
                                           format="yuv420p")
        image.pts = i
        packets = context.encode(image)
        assert [p.pts for p in packets] == [i], f"{codec}: frame {i} in gave packets {[p.pts for p in packets]}"
        decoded = [f for p in packets for f in decoder.decode(p)]
        assert [f.pts for f in decoded] == [i], f"{codec}: the decoder held frame {i} back (reordering)"
        types += [av.video.frame.PictureType(f.pict_type).name for f in decoded]
    assert types[0] == "I" and set(types[1:]) <= {"P", "I"} and "B" not in types, types
    if codec == "H264":
        assert decoder.profile == "Constrained Baseline", decoder.profile
