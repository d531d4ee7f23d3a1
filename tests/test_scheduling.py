"""The event loop's short scheduler slice (core/scheduling.py): taken where the kernel offers it, never passed on."""

from __future__ import annotations

import subprocess
import threading
from pathlib import Path

import pytest

from testbed import processes
from vr_teleop_server.core.scheduling import SHORT_SLICE_S, short_slice, slice_of

SHORT_NS = int(SHORT_SLICE_S * 1e9)


def in_thread(fn):
    out: list = []
    thread = threading.Thread(target=lambda: out.append(fn()))
    thread.start()
    thread.join()
    return out[0]


def kernel_offers_it() -> bool:
    return in_thread(short_slice)


needs_short_slices = pytest.mark.skipif(not kernel_offers_it(), reason="this kernel has no custom slices (< 6.12)")


@needs_short_slices
def test_a_thread_takes_a_short_slice_and_what_it_starts_does_not() -> None:
    def body() -> tuple:
        default = slice_of()
        assert short_slice()
        mine = slice_of()
        child = in_thread(slice_of)
        assert short_slice(0)
        return default, mine, child, slice_of()

    default, mine, child, back = in_thread(body)
    assert mine == SHORT_NS and default > SHORT_NS
    assert child == default and back == default


@needs_short_slices
def test_serve_gives_its_loop_the_short_slice_and_no_other_thread() -> None:
    proc = processes.serve(stderr=subprocess.DEVNULL)
    try:
        slices = {int(tid.name): slice_of(int(tid.name)) for tid in Path(f"/proc/{proc.pid}/task").iterdir()}
        assert slices.pop(proc.pid) == SHORT_NS  # the main thread runs the event loop
        assert slices and all(s is not None and s > SHORT_NS for s in slices.values()), slices
    finally:
        proc.terminate()
        proc.wait(timeout=60)
