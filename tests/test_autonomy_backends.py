"""Issue 39 on a real robot's backends, through testbed/'s fakes: a LuxAI API client's head command (over roslibpy,
to the server) holds the head against a voice that supervised attention would turn to, on a ROS 1 QTrobot (its
rosbridge, the ReSpeaker's voice) and on a QTrobot v3 (LuxAI's hub, its microphone's events); after the grace,
autonomy takes the head back and turns it to the voice. The arbiter is the server's, whatever the robot: the
commands autonomy sends reach the robot only while nobody owns the head.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
import roslibpy
from support import wait_for
from test_autonomy_clients import GRACE, Log
from testbed.luxai_hub import FakeQtrobotV3
from testbed.ros1_rosbridge import Ros1QTrobot

from client_protocol import names
from vr_teleop_server.features.autonomy import AUTONOMY_NODE

WAIT = 60.0  # a failure bound on a loaded machine, never a measure
CLIENT = [-20.0, 5.0]  # where the client puts the head: away from the voice, within both robots' limits
VOICE = 30.0  # the voice's direction in the base frame: left


def held_then_given_back(server, position: Callable[[], float]) -> None:
    """The voice is heard; the client commands the head; the head stays where the client put it, and autonomy sends
    nothing, until the grace after the client's command; then autonomy turns the head to the voice."""
    log = Log(server)
    assert wait_for(lambda: abs(position() - VOICE) <= 10.0, WAIT), position()  # attention turned to the voice
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    head = roslibpy.Topic(ros, names.HEAD_COMMAND_TOPIC, "std_msgs/Float64MultiArray")
    try:
        mark = log.mark()
        head.publish(roslibpy.Message({"data": CLIENT}))
        assert wait_for(lambda: abs(position() - CLIENT[0]) <= 2.0, WAIT), position()
        assert wait_for(lambda: server.call(lambda: server.server.owners.free("head")), WAIT)  # the grace is over
        assert wait_for(lambda: abs(position() - VOICE) <= 10.0, WAIT), position()  # given back: to the voice
        commands = log.since(mark, names.HEAD_COMMAND_TOPIC)
        mine = [e for e in commands if e["sender"] != AUTONOMY_NODE]
        autonomous = [e for e in commands if e["sender"] == AUTONOMY_NODE]
        assert len(mine) == 1 and autonomous
        assert all(e["head"] == "none" for e in autonomous)
        assert autonomous[0]["at"] - mine[0]["at"] >= GRACE
    finally:
        head.unadvertise()
        ros.close()


@pytest.fixture(scope="module")
def ros1() -> Iterator[Ros1QTrobot]:
    fake = Ros1QTrobot()
    yield fake
    fake.stop()


def test_on_a_ros1_robot(ros1: Ros1QTrobot, module_servers):
    server = module_servers(backend="ros", robot_url=ros1.url, autonomy="supervised")
    # the ReSpeaker's angle is the array's own: the base frame's direction less the head's yaw (0 at start)
    ros1.publish(names.RESPEAKER_DIRECTION_TOPIC, {"data": round(0.0 - VOICE) % 360}, latch=True)
    ros1.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": True}, latch=True)
    try:
        held_then_given_back(server, lambda: ros1.positions["HeadYaw"])
    finally:
        ros1.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": False}, latch=True)


def test_on_a_qtrobot_v3(module_servers):
    hub = FakeQtrobotV3().start()
    try:
        server = module_servers(backend="luxai", bystander_interval=0, autonomy="supervised",
                                robot_url=f"tcp://127.0.0.1:{hub.hub_port}")
        hub.mic_event = {"activity": True, "direction": round(VOICE) % 360}  # the head's yaw is 0 at start
        held_then_given_back(server, lambda: hub.positions["HeadYaw"])
    finally:
        hub.mic_event = {"activity": False, "direction": 0}
        hub.stop()
