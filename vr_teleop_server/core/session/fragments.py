"""Reassembly of the fragment op: the pieces of one message, kept until all have come, or dropped when they
disagree, add up to too much, or take too long."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from client_protocol import ops

from .protocol import ProtocolError


@dataclass
class FragmentSet:
    total: int
    parts: dict[int, str]
    size: int
    expiry: asyncio.TimerHandle | None = None


class Reassembly:
    def __init__(self, max_size: int, timeout: float, on_expired: Callable[[Any, int, int], None]) -> None:
        """`on_expired(id, arrived, total)` hears of a set dropped after `timeout` seconds."""
        self.max_size = max_size
        self.timeout = timeout
        self.on_expired = on_expired
        self.sets: dict[Any, FragmentSet] = {}

    def __len__(self) -> int:
        return len(self.sets)

    def add(self, op: ops.Fragment) -> str | None:
        """Keeps one piece; returns the whole message once every piece is in. Raises ProtocolError."""
        limit = self.max_size
        entry = self.sets.get(op.id)
        if entry is None:
            entry = FragmentSet(op.total, {}, 0)
            self.sets[op.id] = entry
            entry.expiry = asyncio.get_running_loop().call_later(self.timeout, self._expire, op.id, entry)
        if op.total != entry.total:
            self.drop(op.id)
            raise ProtocolError(f"fragment {op.num} of id {op.id!r} says total {op.total}, earlier pieces said "
                                f"{entry.total}; the set is discarded")
        if op.num >= op.total:
            raise ProtocolError(f"fragment num {op.num} is out of range for total {op.total} (num counts from 0)")
        previous = entry.parts.get(op.num)
        if previous is not None and previous != op.data:
            self.drop(op.id)
            raise ProtocolError(f"fragment {op.num} of id {op.id!r} arrived twice with different data; "
                                f"the set is discarded")
        if previous is None:
            entry.size += len(op.data)
            entry.parts[op.num] = op.data
        if entry.size > limit:
            self.drop(op.id)
            raise ProtocolError(f"the fragments of id {op.id!r} add up to more than {limit} bytes; discarded")
        if len(entry.parts) == entry.total:
            self.drop(op.id)
            return "".join(entry.parts[i] for i in range(entry.total))
        return None

    def _expire(self, frag_id: Any, entry: FragmentSet) -> None:
        if self.sets.get(frag_id) is entry:
            del self.sets[frag_id]
            self.on_expired(frag_id, len(entry.parts), entry.total)

    def drop(self, frag_id: Any) -> None:
        entry = self.sets.pop(frag_id, None)
        if entry is not None and entry.expiry is not None:
            entry.expiry.cancel()

    def clear(self) -> None:
        for frag_id in list(self.sets):
            self.drop(frag_id)
