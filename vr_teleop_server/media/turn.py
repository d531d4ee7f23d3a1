"""ICE servers with TURN credentials as coturn's `use-auth-secret` checks them (its "TURN REST API"): the server and
the relay share a secret; a client gets username `EXPIRY:KEY` (EXPIRY in s since 1970, KEY the operator key) and
password base64(HMAC-SHA1(secret, username)), which the relay recomputes and accepts until EXPIRY. No account per
client, nothing to revoke: a credential expires by itself.

The secret and the credentials never leave this module except inside an ice-servers response (which the session
keeps out of recordings: its service is confidential) and the server's own RTCConfiguration.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import time
from dataclasses import dataclass, field

from aiortc import RTCIceServer

URL = re.compile(r"^(?P<scheme>stun|stuns|turn|turns):(?P<host>\[[0-9a-fA-F:.]+\]|[^?:\[\]\s]+)(:(?P<port>\d{1,5}))?"
                 r"(\?transport=(?P<transport>udp|tcp))?$")
DEFAULT_TTL_S = 24 * 3600.0  # a day: long enough for a lesson, short enough that a leaked one soon dies
SERVER_KEY = "vr_teleop_server"  # the key in the server's own peer's username


def check_url(url: str) -> str:
    """The URL if it is one RTCIceServer takes (RFC 7064/7065 form), else ValueError naming the fix."""
    m = URL.match(url)
    if m is None:
        raise ValueError(f"{url!r} is not an ICE server URL; write stun:HOST:PORT, turn:HOST:PORT?transport=udp "
                         "(or tcp), or turns:HOST:443?transport=tcp")
    if m["scheme"] == "turns" and m["transport"] == "udp":
        raise ValueError(f"{url!r}: turns: (TURN over TLS) runs over TCP; write ?transport=tcp")
    if m["port"] is not None and not 0 < int(m["port"]) < 65536:
        raise ValueError(f"{url!r}: the port must be 1..65535")
    return url


def is_turn(url: str) -> bool:
    return url.startswith(("turn:", "turns:"))


def credentials(secret: str, key: str, ttl_s: float, now: float) -> tuple[str, str, float]:
    """(username, password, expiry) valid until now + ttl_s for `key`, as coturn's use-auth-secret checks them."""
    expiry = int(now + ttl_s)
    username = f"{expiry}:{key}"
    digest = hmac.new(secret.encode(), username.encode(), hashlib.sha1).digest()
    return username, base64.b64encode(digest).decode("ascii"), float(expiry)


@dataclass(frozen=True)
class IceConfig:
    """The ICE servers a deployment gives every peer: STUN URLs as they are, TURN URLs with credentials made from
    `secret` per request. `repr` leaves the secret out (it goes into logs with the settings)."""

    urls: tuple[str, ...] = ()
    secret: str = field(default="", repr=False)
    ttl_s: float = DEFAULT_TTL_S

    def __post_init__(self) -> None:
        for url in self.urls:
            check_url(url)
        if any(is_turn(u) for u in self.urls) and not self.secret:
            raise ValueError("a TURN URL needs the relay's shared secret: give --turn-secret (coturn's "
                             "static-auth-secret) or $VR_TELEOP_TURN_SECRET")

    def servers(self, key: str, now: float | None = None) -> tuple[list[dict[str, object]], float]:
        """The iceServers entries (urls, username, credential) for `key`, and when the credentials expire (0: none)."""
        now = time.time() if now is None else now
        stun = [u for u in self.urls if not is_turn(u)]
        turn = [u for u in self.urls if is_turn(u)]
        entries: list[dict[str, object]] = [{"urls": stun, "username": "", "credential": ""}] if stun else []
        expires = 0.0
        if turn:
            username, password, expires = credentials(self.secret, key, self.ttl_s, now)
            entries.append({"urls": turn, "username": username, "credential": password})
        return entries, expires

    def rtc(self, key: str = SERVER_KEY) -> list[RTCIceServer]:
        """The same servers for aiortc (the server's own peer). aiortc uses ONE TURN URL, the first given: the
        deployment puts first the one the server itself can reach (behind a firewall that blocks UDP,
        turns:HOST:443?transport=tcp)."""
        return [RTCIceServer(urls=list(e["urls"]), username=str(e["username"]) or None,
                             credential=str(e["credential"]) or None) for e in self.servers(key)[0]]
