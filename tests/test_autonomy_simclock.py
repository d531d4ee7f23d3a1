"""Autonomy on the simulated clock (the server's clock at `--speed max`): a proposal's time-out is kept to one
control tick, and a pupil who speaks is looked at within the design's bound, exactly, whatever the machine's load.
The client is an in-process connection to the server's transport (the same session and frames as a socket's)."""

from __future__ import annotations

import asyncio
import json

import pytest
import simclock
from client_protocol import names
from sim.pupils import pupil
from simclock import SimulatedClock
from vr_teleop_server.app import TeleopServer
from vr_teleop_server.settings import ServerSettings

RULES = """
timeout_s: 1.5
rules:
  - {id: cheer, when: speech_ended, min_speech_s: 0.2, action: emotion.happy, reason: a pupil spoke}
"""


@pytest.mark.slow  # the stand-in's camera drawn and searched for faces through every simulated second
def test_time_outs_and_attention_on_the_simulated_clock(tmp_path):
    (tmp_path / "rules.yaml").write_text(RULES)
    clock = SimulatedClock()
    settings = ServerSettings(port=0, backend="sim", autonomy="supervised", bystander_interval=0, camera_fps=5,
                              autonomy_rules=tmp_path / "rules.yaml", gesture_dir=tmp_path / "g",
                              audio_dir=tmp_path / "a")

    async def main() -> tuple[list[dict], list[tuple[float, float]], float, float]:
        async with TeleopServer(settings, clock) as server:
            conn = server.transport.connect_local()  # a supervisor (open access) watching them: proposals are made
            got: dict[str, list] = {"outcomes": [], "joints": []}

            async def read() -> None:
                async for frame in conn:
                    msg = json.loads(frame)
                    if msg.get("topic") == names.AUTONOMY_OUTCOMES_TOPIC:
                        got["outcomes"].append(msg["msg"])
                    elif msg.get("topic") == names.JOINT_STATE_TOPIC:
                        joints = dict(zip(msg["msg"]["name"], msg["msg"]["position"]))
                        got["joints"].append((clock.monotonic(), joints["HeadYaw"]))

            reader = asyncio.ensure_future(read())
            for topic, type_name in ((names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal"),
                                     (names.AUTONOMY_OUTCOMES_TOPIC, "vr_teleop_msgs/ProposalOutcome"),
                                     (names.JOINT_STATE_TOPIC, "sensor_msgs/JointState")):
                await conn.send(json.dumps({"op": "subscribe", "topic": topic, "type": type_name}))
            await asyncio.sleep(2.0)  # simulated time
            onset = clock.monotonic()
            await conn.send(json.dumps({"op": "call_service", "service": names.SIM_BYSTANDERS_SPEAK_SERVICE,
                                        "args": {"who": "child_left",
                                                 "text": "I know it, the answer is Jupiter, the biggest planet."}}))
            while not got["outcomes"]:
                await asyncio.sleep(0.1)  # simulated time
            reader.cancel()
            return got["outcomes"], got["joints"], onset, server.autonomy.cfg.rate_hz

    outcomes, joints, asked, rate = simclock.run(main(), clock)
    end = outcomes[0]
    assert (end["outcome"], end["decided_by"]) == ("timed_out_executed", "timeout")
    assert 1.5 <= end["seconds"] <= 1.5 + 1.0 / rate  # kept to one control tick
    target = pupil("child_left").yaw_deg
    pointing = next(t for t, yaw in joints if t >= asked and abs(yaw - target) <= 10.0)
    # where the head was when the pupil began (attention may have turned it to a face it sees before)
    start = [yaw for t, yaw in joints if t <= asked][-1]
    # rendering the voice takes no simulated time: the onset is when it was asked; the head is then on the pupil
    # within the confirmation time plus the turn at 60 deg/s plus a tick
    assert pointing - asked <= 0.8 + max(0.0, abs(target - start) - 10.0) / 60.0 + 2.0 / rate, (start, target)


SHOWN_RULES = """
timeout_s: 5.0
rules:
  - {id: cheer, when: speech_ended, min_speech_s: 0.1, action: emotion.happy, reason: a pupil spoke}
"""


@pytest.mark.slow  # the stand-in's camera drawn and searched for faces through every simulated second
def test_a_proposal_is_shown_a_second_before_a_newer_one_replaces_it_and_a_late_page_gets_the_time_left(tmp_path):
    """Two pupils' short answers end within a second: the second proposal waits until the first has been shown
    MIN_SHOWN_S (1 s), then replaces it. A page that opens 2 s later is sent the time really left (`left`), not
    the whole time-out."""
    (tmp_path / "rules.yaml").write_text(SHOWN_RULES)
    clock = SimulatedClock()
    settings = ServerSettings(port=0, backend="sim", autonomy="supervised", bystander_interval=0, camera_fps=5,
                              autonomy_rules=tmp_path / "rules.yaml", gesture_dir=tmp_path / "g",
                              audio_dir=tmp_path / "a")

    async def main() -> tuple[list[tuple[float, dict]], list[dict], dict, float]:
        async with TeleopServer(settings, clock) as server:
            conn = server.transport.connect_local()  # the teacher's page: an audience
            proposals: list[tuple[float, dict]] = []
            outcomes: list[dict] = []

            async def read() -> None:
                async for frame in conn:
                    msg = json.loads(frame)
                    if msg.get("topic") == names.AUTONOMY_PROPOSALS_TOPIC:
                        proposals.append((clock.monotonic(), msg["msg"]))
                    elif msg.get("topic") == names.AUTONOMY_OUTCOMES_TOPIC:
                        outcomes.append(msg["msg"])

            reader = asyncio.ensure_future(read())
            for topic, type_name in ((names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal"),
                                     (names.AUTONOMY_OUTCOMES_TOPIC, "vr_teleop_msgs/ProposalOutcome")):
                await conn.send(json.dumps({"op": "subscribe", "topic": topic, "type": type_name}))
            for who, text in (("child_left", "Yes."), ("child_right", "No.")):
                await conn.send(json.dumps({"op": "call_service", "service": names.SIM_BYSTANDERS_SPEAK_SERVICE,
                                            "args": {"who": who, "text": text}}))
                n = len(proposals)
                while len(proposals) == n:  # the answer's end proposes (the second: once the first was shown 1 s)
                    await asyncio.sleep(0.01)  # simulated time
            await asyncio.sleep(2.0)  # simulated time
            page = server.transport.connect_local()  # a page that opens now
            await page.send(json.dumps({"op": "subscribe", "topic": names.AUTONOMY_STATE_TOPIC,
                                        "type": "vr_teleop_msgs/AutonomyState"}))
            async for frame in page:
                msg = json.loads(frame)
                if msg.get("topic") == names.AUTONOMY_STATE_TOPIC:
                    state = msg["msg"]
                    break
            opened = clock.monotonic()
            reader.cancel()
            return proposals, outcomes, state, opened

    proposals, outcomes, state, opened = simclock.run(main(), clock)
    (t1, first), (t2, second) = proposals[:2]
    assert 1.0 <= t2 - t1 <= 1.0 + 0.1  # queued: proposed when the first had been shown its second, not later
    end = next(o for o in outcomes if o["id"] == first["id"])
    assert end["outcome"] == "superseded" and end["seconds"] >= 1.0
    assert [p["id"] for p in state["pending"]] == [second["id"]]
    assert state["pending"][0]["left"] == pytest.approx(5.0 - (opened - t2), abs=0.1)
