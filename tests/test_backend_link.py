"""The link's rule for lost and back, and its voice news, without I/O (robot/link.py): facts and times in,
decisions out. The backends that feed it are tested for real in test_backend_ros1.py and test_backend_luxai.py."""

from __future__ import annotations

import socket

import pytest

from vr_teleop_server.robot.backends import BACKEND_NAMES, BACKENDS, BackendFactory
from vr_teleop_server.robot.backends.ros import respeaker_to_base
from vr_teleop_server.robot.link import (
    DIRECTION_STEP_DEG,
    LOST_AFTER_S,
    RETRY_MAX_S,
    RETRY_MIN_S,
    LinkState,
    RobotDisconnected,
    RobotLinkError,
    RobotUnreachable,
    VoiceNews,
)
from client_protocol.errors import Refusal
from vr_teleop_server.settings import ServerSettings


def opened(at: float = 0.0) -> LinkState:
    link = LinkState()
    link.opened(at)
    return link


def test_connected_while_joint_states_flow_and_lost_once_they_stop_for_lost_after():
    link = opened()
    assert link.connected and link.tick(LOST_AFTER_S * 0.9) is None  # the first heartbeat has LOST_AFTER_S
    link.heartbeat(LOST_AFTER_S * 0.9)
    assert link.tick(LOST_AFTER_S * 1.5) is None and link.connected
    assert link.tick(LOST_AFTER_S * 1.9 + 0.01) == "lost"
    assert not link.connected and link.reason == f"no joint state for {LOST_AFTER_S:g} s"
    assert link.tick(LOST_AFTER_S * 3) is None  # said once


def test_a_closed_connection_is_lost_at_once_and_back_only_with_joint_states_again():
    link = opened()
    link.heartbeat(0.1)
    link.transport(False)
    assert link.tick(0.2) == "lost" and link.reason == "the connection closed"
    link.transport(True)
    assert link.tick(0.3) is None  # the socket is back, the robot's nodes not yet
    link.heartbeat(0.4)
    assert link.tick(0.45) == "resume" and not link.connected  # only once the backend has resumed
    assert link.resumed(True, 0.45) and link.connected and link.reason == ""
    assert link.tick(0.5) is None


def test_a_resume_that_fails_is_retried_with_a_doubling_backoff():
    link = opened()
    assert link.tick(LOST_AFTER_S + 0.1) == "lost"
    now, waits = 10.0, []
    link.heartbeat(now)
    for _ in range(6):
        assert link.tick(now) == "resume"
        assert not link.resumed(False, now)
        retry = now
        while link.tick(retry) is None:  # refused meanwhile: commands stay refused while not connected
            assert not link.connected
            link.heartbeat(retry)
            retry += 0.05
        waits.append(round(retry - now, 1))
        now = retry
    assert waits == [RETRY_MIN_S, 2 * RETRY_MIN_S, 4 * RETRY_MIN_S, 8 * RETRY_MIN_S, RETRY_MAX_S, RETRY_MAX_S]
    assert link.resumed(True, now)
    assert link.tick(now + LOST_AFTER_S + 0.1) == "lost"  # and the backoff starts afresh for the next loss
    link.heartbeat(now + 2)
    assert link.tick(now + 2) == "resume" and not link.resumed(False, now + 2)
    assert link.tick(now + 2 + RETRY_MIN_S * 0.9) is None and link.tick(now + 2 + RETRY_MIN_S) == "resume"


def test_voice_news_is_a_start_a_stop_or_a_move_while_speaking():
    news = VoiceNews()
    assert news.update(False, None)  # the first report tells the state
    assert not news.update(None, 40.0)  # a direction while nobody speaks is no news
    assert news.update(True, None) and news.direction == 40.0  # a voice starts, where the array last pointed
    assert not news.update(None, 40.0 + DIRECTION_STEP_DEG * 0.5)  # the estimate wanders
    assert news.update(None, 40.0 + DIRECTION_STEP_DEG)  # the voice moved
    assert news.update(None, 350.0) and not news.update(None, 355.0)  # across 0: the smaller angle counts
    assert news.update(False, None) and not news.speaking
    assert not news.update(False, 100.0)


@pytest.mark.parametrize(("array", "head_yaw", "base"), [
    (0, 0.0, 0.0),  # straight at the face
    (90, 0.0, -90.0),  # the array's angle grows clockwise: towards the robot's right, negative in the base frame
    (270, 0.0, 90.0),
    (180, 0.0, -180.0),
    (0, 30.0, 30.0),  # the array turns with the head
    (350, 20.0, 30.0),
    (200, -60.0, 100.0),
])
def test_the_respeakers_angle_in_the_base_frame(array, head_yaw, base):
    assert respeaker_to_base(array, head_yaw) == pytest.approx(base)


def test_one_exception_family_and_one_table_of_backends():
    assert issubclass(RobotUnreachable, RobotLinkError) and issubclass(RobotDisconnected, RobotLinkError)
    assert issubclass(RobotDisconnected, Refusal)  # the client reads its message
    assert not issubclass(RobotUnreachable, RuntimeError)
    assert BACKEND_NAMES == tuple(BACKENDS) == ("sim", "ros", "luxai", "none")
    field = ServerSettings.model_fields["backend"]
    assert all(f"'{name}'" in field.description for name in BACKEND_NAMES)
    for name, backend in BACKENDS.items():
        assert ServerSettings(backend=name).resolved_robot_url == (backend.default_url or "")
    with pytest.raises(ValueError, match="ws://HOST:PORT"):
        BACKENDS["ros"].check_url("http://robot:9090")
    with pytest.raises(ValueError, match="--robot-id"):
        BACKENDS["luxai"].check_url("mqtt://broker:1883")
    BACKENDS["sim"].check_url("anything")  # no robot URL to check
    for name, backend in BACKENDS.items():  # each class is what the server asks of a backend's
        if backend.factory is not None:
            cls = backend.load()
            assert isinstance(cls, BackendFactory) and cls.backend == name


async def test_construction_does_no_io_and_open_says_when_the_robot_cannot_be_reached():
    """A backend is built without touching the network (so that it can be wired first); open() reaches the robot
    or raises RobotUnreachable with the reason; roslibpy's reconnect backoff is set on that connection only."""
    from roslibpy.comm.comm_autobahn import AutobahnRosBridgeClientFactory

    from vr_teleop_server.robot.backends.luxai import LuxaiRobot
    from vr_teleop_server.robot.backends.ros import RosRobot

    delays = (AutobahnRosBridgeClientFactory.initialDelay, AutobahnRosBridgeClientFactory.maxDelay)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for robot in (RosRobot(f"ws://127.0.0.1:{port}", connect_timeout=1.0),
                  LuxaiRobot(f"tcp://127.0.0.1:{port}", connect_timeout=1.0)):
        assert not robot.connected and robot.info["connected"] is False
        assert robot.set_joint_targets({"HeadYaw": 10.0}).ignored == ("HeadYaw",)  # nothing to send it to
        with pytest.raises(RobotUnreachable, match=f"127.0.0.1:{port}"):
            await robot.open()
        await robot.aclose()
    assert (AutobahnRosBridgeClientFactory.initialDelay, AutobahnRosBridgeClientFactory.maxDelay) == delays
