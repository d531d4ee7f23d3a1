"""The media loop: aiortc's peers on an event loop of their own, in a thread started and stopped with the media
service, so that their per-packet work (RTP packetization, SRTP, RTCP, SCTP, pacing, Opus) never sits in the
queue of the loop that carries the poses.

Who owns what: the peer connections, their tracks and their data channels live on the media loop and are only
touched there; the bus, the sessions, the robot and the hubs that feed the tracks (VideoHub, AudioMixer) live on
the server's loop. Work crosses in two ways only: `run` (a coroutine on the media loop, awaited from the server's
loop) and `call_on` (a plain call queued onto the other loop with `call_soon_threadsafe`, which keeps the order of
the calls). Plain counters that one side writes and the other reads (frames sent, the peer's bitrate estimate) are
read without a hop: a read of one attribute is atomic in CPython.

Lifecycle as py_trees behaviours have it: `setup` starts the thread and returns once its loop runs; `shutdown`
cancels what is left on it, stops it and joins the thread, so nothing keeps running after the service stops.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import ctypes
import logging
import threading
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")
THREAD_NAME = "media-loop"
SHUTDOWN_TIMEOUT_S = 10.0


def call_on(loop: asyncio.AbstractEventLoop, fn: Callable[..., Any], *args: Any) -> None:
    """`fn(*args)` on `loop`: at once when that loop is the one running here, else queued in call order."""
    try:
        running = asyncio.get_running_loop()
    except RuntimeError:
        running = None
    if running is loop:
        fn(*args)
    else:
        loop.call_soon_threadsafe(fn, *args)


class MediaLoop:
    """One event loop in one thread, for the WebRTC peers."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self.thread: threading.Thread | None = None
        self._ended: concurrent.futures.Future[None] | None = None

    def setup(self) -> None:
        """Starts the thread; returns once its loop runs."""
        if self.thread is not None:
            return
        loop = asyncio.new_event_loop()
        ready = threading.Event()
        ended = self._ended = concurrent.futures.Future()

        def main() -> None:
            with contextlib.suppress(Exception):  # Linux: the name `top -H` and /proc show (prctl PR_SET_NAME)
                ctypes.CDLL(None).prctl(15, THREAD_NAME.encode(), 0, 0, 0)
            asyncio.set_event_loop(loop)
            loop.call_soon(ready.set)
            try:
                loop.run_forever()
            finally:
                loop.close()
                ended.set_result(None)

        self.thread = threading.Thread(target=main, name=THREAD_NAME, daemon=True)
        self.thread.start()
        ready.wait()
        self.loop = loop

    async def run(self, coro: Coroutine[Any, Any, T]) -> T:
        """Runs `coro` on the media loop and waits for it here (on the server's loop); cancelling the wait
        cancels it there."""
        if self.loop is None:
            coro.close()
            raise RuntimeError("the media loop is not running (MediaLoop.setup not called, or shut down)")
        return await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(coro, self.loop))

    async def shutdown(self) -> None:
        """Cancels the tasks left on the media loop, lets them unwind, stops the loop and joins the thread."""
        loop, thread = self.loop, self.thread
        if loop is None or thread is None:
            return
        self.loop = self.thread = None

        async def drain() -> None:
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            if tasks:
                await asyncio.wait(tasks, timeout=SHUTDOWN_TIMEOUT_S)
            await loop.shutdown_asyncgens()

        try:
            await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(drain(), loop))
        except Exception:
            log.exception("the media loop's tasks did not all finish")
        loop.call_soon_threadsafe(loop.stop)
        assert self._ended is not None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.wrap_future(self._ended), SHUTDOWN_TIMEOUT_S)
        if self._ended.done():
            thread.join()  # its last step after the loop closed
        else:
            log.error("the media loop's thread did not stop within %g s", SHUTDOWN_TIMEOUT_S)
