"""The operator's voice over rosbridge takes the one road (features/speech.py's OperatorVoiceIn) to the stand-in:
a client's 48 kHz stereo AudioData moves its mouth, owns the robot's voice while it comes (autonomy never talks
over it) and is logged as it came. The same road to the ROS 1 robot's
speaker topic and the v3's media stream is tested in test_backend_ros1.py and test_backend_luxai.py; WebRTC's
in test_media.py (the stand-in), test_backend_ros.py and test_backend_luxai.py."""

from __future__ import annotations

import pytest
import roslibpy
from operator_voice import VoiceSender, logged, tone
from support import wait_for


@pytest.fixture
def server(servers):
    return servers(backend="sim", bystander_interval=0)


def test_a_clients_voice_over_rosbridge_moves_the_standins_mouth_and_is_logged(server):
    robot = server.server.robot
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    try:
        assert server.call(lambda: robot.voice_level) == 0.0
        pcm = tone(2.0, 48000, 2)
        sender = VoiceSender(ros, pcm, 48000, 2).start()
        talking = []  # the voice's owner read on the server's loop at the moment the mouth is open

        def mouth_open() -> bool:
            level, owner = server.call(lambda: (robot.voice_level, server.server.owners.owner("voice")))
            if level > 0.5:
                talking.append(owner)
            return level > 0.5 or sender.done.is_set()

        assert wait_for(mouth_open, 30)
        assert not sender.done.is_set(), "the mouth did not open while the voice came"
        assert talking == ["client"], talking  # the operator's voice owns the robot's while it comes
        assert sender.done.wait(30)
        assert wait_for(lambda: logged(server.settings.audio_dir) == (48000, 2, pcm), 30)
        assert wait_for(lambda: server.call(lambda: robot.voice_level) == 0.0, 30)  # it closes after the voice
    finally:
        ros.close()
