"""The frame ring (worker_process/frame_ring.py): raw frames in shared memory, newest wins, torn reads refused."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from worker_process.frame_ring import NAME, FrameRing


def holds_ring(pid: int) -> bool:
    """Whether process `pid` has a frame ring open or mapped."""
    fds = Path(f"/proc/{pid}/fd")
    for fd in fds.iterdir():
        try:
            if NAME in os.readlink(fd):
                return True
        except OSError:
            continue
    return NAME in Path(f"/proc/{pid}/maps").read_text()


def test_a_reader_gets_the_frame_until_a_newer_one_takes_its_slot() -> None:
    ring = FrameRing.create(8, 4, slots=2)
    writer = FrameRing.attach((ring.dup(), 8, 4, 2))
    reader = FrameRing.attach((ring.dup(), 8, 4, 2))
    try:
        writer.begin(1)[:] = 11
        assert reader.read(1, np.copy) is None  # begun, not committed: not there yet
        writer.commit(1)
        writer.begin(2)[:] = 22
        writer.commit(2)
        assert (reader.read(1, np.copy) == 11).all() and (reader.read(2, np.copy) == 22).all()
        writer.begin(3)[:] = 33  # slot 1 again: frame 1 is gone, even before 3 is committed
        assert reader.read(1, np.copy) is None
        writer.commit(3)
        assert reader.read(1, np.copy) is None and (reader.read(3, np.copy) == 33).all()

        def overwritten_meanwhile(pixels: np.ndarray) -> np.ndarray:
            out = pixels.copy()
            writer.begin(5)[:] = 55  # the writer laps the reader while it copies
            writer.commit(5)
            return out

        assert reader.read(3, overwritten_meanwhile) is None
    finally:
        for r in (writer, reader):
            r.close()
        ring.close()


def is_ring(fd: int) -> bool:
    """Whether descriptor `fd` of this process is (still) a frame ring."""
    try:
        return NAME in os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return False


def test_closing_releases_the_memory_and_refuses_new_workers() -> None:
    ring = FrameRing.create(640, 480)
    fd = ring.fd
    assert is_ring(fd)
    ring.close()
    ring.close()  # twice is harmless
    assert ring.dup() is None
    assert not is_ring(fd)
