"""The event loop's thread asks Linux for short scheduler slices, so that media work cannot make a pose wait.

On a busy machine a thread that wakes (a pose arrived) waits until the running one has used its slice: Linux's
EEVDF scheduler lets the current task run to its deadline, about 1.4 ms on 2 cores, whatever the niceness of either.
Since Linux 6.12 a SCHED_OTHER thread may ask for a shorter slice (`sched_attr.sched_runtime`, 0.1 to 100 ms); a
waking thread with a shorter slice than the running one preempts it at once. The server's loop asks for one; the
render process, the encoder and every other thread it starts keep the default (reset on fork), so its wakeups win
over them. Its share of the CPU is unchanged: a short slice changes when a thread runs, not how much.

Where the call is not available (another OS, an older kernel, a seccomp filter), nothing changes and the server
runs as before.
"""

from __future__ import annotations

import ctypes
import logging
import os
import platform
import struct
import threading

_log = logging.getLogger(__name__)

SHORT_SLICE_S = 100e-6  # the kernel's lower bound: wake-ups preempt at once
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}
_SCHED_OTHER = 0
_SCHED_FLAG_RESET_ON_FORK = 0x01
_ATTR = struct.Struct("IIQiIQQQII")  # struct sched_attr, SCHED_ATTR_SIZE_VER1 (56 bytes)


def short_slice(slice_s: float = SHORT_SLICE_S, tid: int = 0) -> bool:
    """Gives the calling thread (or thread `tid`) a short slice, 0 for the default back; threads and processes it
    starts later get the default. True if the kernel took it."""
    number = _SYS_SCHED_SETATTR.get(platform.machine())
    if platform.system() != "Linux" or number is None:
        return False
    tid = tid or threading.get_native_id()
    ns = int(slice_s * 1e9)
    try:
        nice = os.getpriority(os.PRIO_PROCESS, tid)
    except OSError:
        return False
    attr = ctypes.create_string_buffer(_ATTR.pack(_ATTR.size, _SCHED_OTHER, _SCHED_FLAG_RESET_ON_FORK, nice, 0, ns,
                                                  0, 0, 0, 0), _ATTR.size)
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.syscall(number, tid, attr, 0) != 0:
        _log.debug("no short scheduler slice: %s", os.strerror(ctypes.get_errno()))
        return False
    return ns == 0 or slice_of(tid) == ns


def slice_of(tid: int = 0) -> int | None:
    """A thread's slice in ns as the kernel reports it (None where it does not)."""
    tid = tid or threading.get_native_id()
    try:
        with open(f"/proc/{tid}/sched") as f:
            for line in f:
                if line.startswith("se.slice"):
                    return int(line.split(":")[1])
    except (OSError, ValueError):
        pass
    return None
