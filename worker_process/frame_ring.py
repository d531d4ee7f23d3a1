"""Raw camera frames shared between processes without a copy through a socket: a ring of frame slots in memory.

The stand-in's render process draws each camera frame straight into a slot; the video encoder process reads it
from there, so a frame is compressed once (to VP8 or H.264), not first to JPEG to cross a socket. The ring is an
anonymous memory file (memfd) rather than a named `multiprocessing.shared_memory` block: it has no name under
/dev/shm that a crashed server would leave behind (or a resource-tracker process to clean it up), and the kernel
frees it when the last process holding it closes or dies. Its owner passes the descriptor to each worker at
start (`WorkerProcess(pass_fds=...)`); a worker maps it.

Newest wins: frame `seq` goes to slot `seq % slots`, overwriting whatever was there. Each slot starts with a
header holding the seq of the frame it holds, 0 while the writer is filling it (a sequence lock): a reader checks
the seq before and after it reads the pixels and drops the frame if a newer one was written meanwhile.
"""

from __future__ import annotations

import mmap
import os
import threading
from typing import Any

HEADER = 64  # bytes before each slot's pixels: the seq of the frame held (little-endian int64), 0 while written
SLOTS = 4  # at 30 fps a reader has 100 ms to read a frame before the writer comes back to its slot
NAME = "vr-teleop-frames"  # how the memory file shows in /proc/PID/fd and /proc/PID/maps


class FrameRing:
    """A ring of `slots` RGB frames of width x height. The creating process owns the descriptor (`close` it when
    done); `attach` maps one in a worker. Writing and reading need NumPy; holding the descriptor does not."""

    def __init__(self, fd: int, width: int, height: int, slots: int = SLOTS) -> None:
        self.fd = fd
        self.width, self.height, self.slots = int(width), int(height), int(slots)
        pixels = self.width * self.height * 3
        self.slot_bytes = HEADER + (pixels + 63) // 64 * 64
        self._lock = threading.Lock()  # against close() while another thread dups the descriptor
        self._map: mmap.mmap | None = None
        self._views: list[tuple[Any, Any]] = []  # per slot: (header as int64[1], pixels as uint8[h, w, 3])

    @classmethod
    def create(cls, width: int, height: int, slots: int = SLOTS) -> FrameRing:
        fd = os.memfd_create(NAME, os.MFD_CLOEXEC)
        ring = cls(fd, width, height, slots)
        try:
            os.ftruncate(fd, ring.slots * ring.slot_bytes)
        except BaseException:
            os.close(fd)
            raise
        return ring

    @classmethod
    def attach(cls, spec: tuple[int, int, int, int]) -> FrameRing:
        """In a worker: the ring whose `spec()` the owner sent, its descriptor passed with pass_fds."""
        ring = cls(*spec)
        ring._mapped()
        return ring

    def spec(self) -> tuple[int, int, int, int]:
        return self.fd, self.width, self.height, self.slots

    def dup(self) -> int | None:
        """A descriptor of the ring for a worker about to start (the caller closes it), None once it is closed."""
        with self._lock:
            return None if self.fd < 0 else os.dup(self.fd)

    def slot_of(self, seq: int) -> int:
        return seq % self.slots

    def _mapped(self) -> list[tuple[Any, Any]]:
        if self._map is None:
            import numpy as np

            self._map = mmap.mmap(self.fd, self.slots * self.slot_bytes)
            for i in range(self.slots):
                start = i * self.slot_bytes
                header = np.frombuffer(self._map, np.int64, 1, start)
                pixels = np.frombuffer(self._map, np.uint8, self.width * self.height * 3, start + HEADER)
                self._views.append((header, pixels.reshape(self.height, self.width, 3)))
        return self._views

    # ---- the writer (the render process) ----
    def begin(self, seq: int) -> Any:
        """The pixels of frame `seq`'s slot, marked as being written: fill them, then `commit(seq)`."""
        header, pixels = self._mapped()[self.slot_of(seq)]
        header[0] = 0
        return pixels

    def commit(self, seq: int) -> None:
        self._mapped()[self.slot_of(seq)][0][0] = seq

    # ---- a reader (the encoder process) ----
    def read(self, seq: int, convert: Any) -> Any:
        """`convert(pixels)` of frame `seq` (it must copy what it keeps), or None when the slot no longer holds that
        frame (a newer one overwrote it before or while it was read)."""
        header, pixels = self._mapped()[self.slot_of(seq)]
        if int(header[0]) != seq:
            return None
        out = convert(pixels)
        return out if int(header[0]) == seq else None

    def close(self) -> None:
        """Unmap and close this process's hold on the ring; the memory goes once every process has let go."""
        with self._lock:
            self._views.clear()
            if self._map is not None:
                try:
                    self._map.close()
                except BufferError:  # a caller still holds a view: the mapping goes when that view does
                    pass
                self._map = None
            if self.fd >= 0:
                os.close(self.fd)
                self.fd = -1
