"""Roles and what each may do: one policy, consulted by every session before it runs an op.

Roles: operator (drives the robot: may engage control, send poses and Joy, run menu commands), supervisor
(everything, including taking control away from the operator), spectator (reads: subscribes, and calls only
read-only services). Tokens are given with `serve --operator-token/--supervisor-token/--spectator-token`, the
environment (VR_TELEOP_OPERATOR_TOKEN, ...), or `--generate-tokens`; a client presents one with the rosbridge
`auth` op (the token in `mac`) before anything else. Without tokens the server is open: every client is a
supervisor, and serve binds to loopback only unless told `--insecure`.

With `serve --blur-faces`, only an operator and a supervisor see faces (they must see the pupils): a spectator's
subscription to a camera topic is served from its face-blurred stand-in (`blurred_views`), and its WebRTC video is
blurred too (media/service.py).

A live study (`serve --study`) adds the participant role: each participant's page has a token of its own (from
/study/participants/add), known to the study folder, which admits only that participant's questionnaires, with
tokens or without.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import os
import secrets
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal
from urllib.parse import parse_qs, urlsplit

from client_protocol import names

Role = Literal["operator", "supervisor", "spectator", "participant"]
ROLES: tuple[Role, ...] = ("operator", "supervisor", "spectator")  # the roles given by serve's token flags
ENV = {role: f"VR_TELEOP_{role.upper()}_TOKEN" for role in ROLES}
# What a spectator may call: services that only read.
READ_ONLY_SERVICES_PREFIXES = ("/rosapi/",)
# The media offer is a read, as the camera topic is: a spectator's microphone is not played (media/service.py).
READ_ONLY_SERVICES = {names.GESTURE_LIST_SERVICE, names.MEDIA_OFFER_SERVICE, names.MEDIA_ICE_SERVERS_SERVICE,
                      names.CLOCK_SERVICE,
                      names.WHOAMI_SERVICE, names.FILE_SERVER_SERVICE}
# What only a supervisor may do on top of an operator.
SUPERVISOR_ONLY_SERVICES = {names.MOTIVATION_SET_SERVICE, names.MOTIVATION_RESET_SERVICE, names.CLIP_ADD_SERVICE,
                            names.CLIP_REMOVE_SERVICE, names.STUDY_PARTICIPANT_ADD_SERVICE,
                            names.STUDY_TRIAL_START_SERVICE, names.STUDY_TRIAL_END_SERVICE, names.STUDY_NOTE_SERVICE}
# All a participant's page may call: their own questionnaires.
PARTICIPANT_SERVICES = {names.STUDY_QUESTIONNAIRE_DUE_SERVICE, names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE}
PARTICIPANT_OPS = {"auth", "status", "fragment", "set_level"}
READ_OPS = {"subscribe", "unsubscribe", "set_level", "status", "fragment", "auth"}


class AccessDenied(Exception):
    pass


@dataclass(frozen=True)
class Login:
    """What a connection said at its WebSocket handshake (ROS# has no auth op: the URL is all it has)."""
    role: Role | None = None
    operator: str = ""  # the operator key ("" : the connection is its own operator)
    time_style: Literal["ros1", "ros2"] | None = None


TIME_STYLES = ("ros1", "ros2")


@dataclass(frozen=True)
class AccessPolicy:
    tokens: dict[str, Role]  # token -> role; empty: open access
    # a live study's participant tokens: token -> participant id, or None (study/folder.py makes them)
    participants: Callable[[str], str | None] | None = field(default=None, compare=False)
    # serve --blur-faces: a topic -> the topic with its faces blurred, which is what a role that may not see faces gets
    blurred_views: dict[str, str] = field(default_factory=dict)

    def participant(self, token: str) -> str | None:
        return self.participants(token) if self.participants is not None and token else None

    @property
    def open(self) -> bool:
        return not self.tokens

    def role_for(self, token: str) -> Role | None:
        for known, role in self.tokens.items():
            if hmac.compare_digest(known.encode(), token.encode()):
                return role
        return "participant" if self.participant(token) is not None else None

    def operator_key(self, token: str) -> str:
        """A stable name for everyone presenting `token`, which does not reveal it (a hash prefix); a participant's
        is `participant:P03`, which the study's services read."""
        pid = self.participant(token)
        if pid is not None:
            return f"participant:{pid}"
        return "op-" + hashlib.sha256(b"vr-teleop operator\0" + token.encode()).hexdigest()[:12] if token else ""

    def login(self, path: str, authorization: str | None) -> Login:
        """The role, operator and time style a handshake asks for: `?token=` (or `Authorization: Bearer`),
        `?operator=KEY` (open access only: one operator's connections without tokens), `?time=ros1|ros2`.
        Raises AccessDenied with the reason (never the token) for a token not known, ValueError for a query
        that asks for something impossible."""
        query = parse_qs(urlsplit(path).query)
        token = (query.get("token") or [""])[-1]
        if authorization:
            scheme, _, value = authorization.strip().partition(" ")
            if scheme.lower() != "bearer" or not value.strip():
                raise AccessDenied("the Authorization header must be 'Bearer <token>'")
            token = token or value.strip()
        role: Role | None = None
        operator = ""
        if token:
            role = self.role_for(token)
            if role is None:
                raise AccessDenied("the token is not known to this server")
            operator = self.operator_key(token)
        key = (query.get("operator") or [""])[-1]
        if key:
            if not self.open:
                raise ValueError("?operator= is for open access only; with tokens, the operator is the token")
            operator = self.operator_key("key:" + key)
        style = (query.get("time") or [None])[-1]
        if style is not None and style not in TIME_STYLES:
            raise ValueError(f"?time= must be ros1 or ros2, not {style[:20]!r}")
        return Login(role, operator, style)  # type: ignore[arg-type]

    def check(self, role: Role | None, op: str, target: str = "") -> None:
        """Raises AccessDenied saying what the role may not do."""
        if role == "participant":
            if op in PARTICIPANT_OPS or (op == "call_service" and target in PARTICIPANT_SERVICES):
                return
            raise AccessDenied(f"role participant may not {op.replace('_', ' ')}{' ' + target if target else ''}: a "
                               "participant's page only fills in their own questionnaires")
        if self.open:
            return
        if role is None:
            if op != "auth":
                raise AccessDenied('authenticate first: send {"op": "auth", "mac": "<your token>"}')
            return
        if role == "supervisor" or op in READ_OPS:
            return
        if role == "spectator":
            if op == "call_service" and (target in READ_ONLY_SERVICES
                                         or target.startswith(READ_ONLY_SERVICES_PREFIXES)):
                return
            raise AccessDenied(f"role spectator may not {op.replace('_', ' ')}{' ' + target if target else ''}: "
                               "spectators only watch")
        if op == "call_service" and target in SUPERVISOR_ONLY_SERVICES:
            raise AccessDenied(f"role operator may not call {target}: only a supervisor may")

    def sees_faces(self, role: Role | None) -> bool:
        """Whether a role gets the camera as it is; without --blur-faces everyone who may watch it does."""
        return not self.blurred_views or self.open or role in ("operator", "supervisor")

    def topic_view(self, role: Role | None, topic: str) -> str:
        """The topic that serves `role`'s subscription to `topic`: its blurred view for a role that may not see
        faces."""
        return topic if self.sees_faces(role) else self.blurred_views.get(topic, topic)

    def may_override_control(self, role: Role | None) -> bool:
        """Whether a caller may take control away from whoever holds it."""
        return self.open or role == "supervisor"


def generate_tokens() -> dict[Role, str]:
    return {role: secrets.token_urlsafe(18) for role in ROLES}


def tokens_from(flags: dict[Role, str | None]) -> dict[str, Role]:
    """Flags first, then the environment; token -> role."""
    out: dict[str, Role] = {}
    for role in ROLES:
        token = flags.get(role) or os.environ.get(ENV[role])
        if token:
            if token in out:
                raise ValueError(f"the {role} token is the same as the {out[token]} token; give each role its own")
            out[token] = role
    return out


def is_loopback(host: str) -> bool:
    if host in ("localhost", ""):
        return host == "localhost"
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
