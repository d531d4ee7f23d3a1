"""The media loop (issue 29): aiortc's peers run on an event loop of their own, in a thread the media service starts
and stops; poses arriving on the data channel still go through the client's own session on the server's loop, in
the order they arrived. A real aiortc peer, the stand-in, an in-process server (to see its threads)."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from typing import Any

import pytest

from testbed.media_client import MediaPeer, Rosbridge
from testbed.server import Pace, until
from test_datachannel import HEAD_POSE, engage_over_websocket, head_pose, release, whoami
from vr_teleop_server.media.media_loop import THREAD_NAME, MediaLoop

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]  # WebRTC peers with the stand-in

POSES = 60


def media_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == THREAD_NAME]


def task_names(loop: asyncio.AbstractEventLoop) -> set[str]:
    """The qualified names of the coroutines of the tasks on `loop` (asyncio.all_tasks retries a concurrent
    change of its set)."""
    return {getattr(t.get_coro(), "__qualname__", "") for t in asyncio.all_tasks(loop)}


async def test_the_peers_run_on_the_media_loop_poses_reach_the_session_in_order_and_stop_leaves_no_thread(
        servers) -> None:
    before = len(media_threads())
    server = servers(backend="sim", bystander_interval=0, camera_fps=10)
    stopped = False
    try:
        media = server.server.media
        thread = server.call(lambda: media.media_loop.thread)
        assert thread is not None and thread.is_alive() and thread is not server.thread
        assert len(media_threads()) == before + 1

        published: list[tuple[str, float, bool]] = []  # (sender, x, on the server's loop's thread)

        def on_pose(message: Any) -> None:
            x = message.data["pose"]["position"]["x"]
            published.append((message.sender, x, threading.current_thread() is server.thread))

        token = server.call(lambda: server.server.bus.subscribe("/test", HEAD_POSE, "geometry_msgs/PoseStamped",
                                                                on_pose))
        ros = await Rosbridge.open(server.url)
        client = MediaPeer(audio=False)
        # Ordered and reliable here, so that the order the server sees is the order sent: what is tested is that
        # the hop from the media loop to the session keeps it.
        channel = client.pc.createDataChannel("poses", ordered=True)
        reply = await client.negotiate(ros)
        assert reply["values"]["success"], reply
        await client.wait_video(3)
        assert await until(lambda: channel.readyState == "open", 30)
        name = await whoami(ros)

        # aiortc's transports run on the media loop, none of them on the server's.
        media_tasks = await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(
            asyncio.sleep(0, task_names(media.media_loop.loop)), media.media_loop.loop))
        assert any(n.startswith(("RTCSctpTransport", "RTCDtlsTransport", "RTCRtpSender")) for n in media_tasks), \
            media_tasks
        home_tasks = server.call(lambda: task_names(server.loop))
        assert not any(n.startswith(("RTCSctpTransport", "RTCDtlsTransport", "RTCRtpSender", "RTCIce"))
                       for n in home_tasks), home_tasks

        await engage_over_websocket(ros)
        server.call(published.clear)
        t0 = time.time()
        pace = Pace(100)  # ten poses at a time, a hundred times a second
        for k in range(POSES):
            msg = head_pose(0.0, t0 + k * 0.001)
            msg["pose"]["position"]["x"] = k / 1000
            channel.send(json.dumps({"op": "publish", "topic": HEAD_POSE, "msg": msg}))
            if k % 10 == 9:
                await pace.tick()
        await until(lambda: server.call(lambda: len(published)) >= POSES, 30, blocking=True)
        seen = server.call(lambda: list(published))
        # Every pose, through the session (its name as sender), on the server's loop, in the order sent.
        assert [x for _, x, _ in seen] == pytest.approx([k / 1000 for k in range(POSES)]), seen
        assert all(sender == name for sender, _, _ in seen), seen
        assert all(home for _, _, home in seen)
        await release(ros)
        server.call(lambda: server.server.bus.unsubscribe(HEAD_POSE, token))
        await client.close()
        await ros.close()
        server.stop()
        stopped = True
        assert not thread.is_alive()
        assert len(media_threads()) == before
        assert media.media_loop.loop is None and media.media_loop.thread is None
    finally:
        if not stopped:
            server.stop()


async def test_the_media_loop_runs_work_in_its_thread_and_shutdown_cancels_what_is_left() -> None:
    media = MediaLoop()
    media.setup()
    thread = media.thread
    assert thread is not None and thread.is_alive() and thread is not threading.current_thread()
    unwound = threading.Event()

    async def where() -> threading.Thread:
        return threading.current_thread()

    async def forever() -> None:
        try:
            await asyncio.Event().wait()  # until cancelled
        finally:
            unwound.set()

    assert await media.run(where()) is thread
    assert media.loop is not None
    asyncio.run_coroutine_threadsafe(forever(), media.loop)
    await media.shutdown()
    assert unwound.is_set() and not thread.is_alive()
    with pytest.raises(RuntimeError, match="not running"):
        await media.run(where())
