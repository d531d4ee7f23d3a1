"""The pure parts of supervised autonomy: attention's scoring and hysteresis, the ownership arbiter, the rules file
and the learner's memory (features/autonomy, core/ownership.py)."""

from __future__ import annotations

import json
import math

import pytest
from client_protocol.vocabulary import Outcome, Owner, Part
from hypothesis import given, settings
from hypothesis import strategies as st

from vr_teleop_server.core.ownership import Ownership
from vr_teleop_server.features.autonomy.attention import Attention, AttentionConfig, Candidate, load_config, score
from vr_teleop_server.features.autonomy.learner import Learner, Situation
from vr_teleop_server.features.autonomy.rules import check_actions, load_rules

CFG = AttentionConfig()
DT = 1.0 / CFG.rate_hz


def run(att: Attention, start: float, seconds: float, candidates) -> list:
    """Ticks at the attention's rate; `candidates(now)` gives what perception holds at each."""
    out, n = [], int(round(seconds / DT))
    for i in range(1, n + 1):
        now = start + i * DT
        out.append((now, att.update(now, candidates(now))))
    return out


def test_the_packaged_configuration_holds_luxais_figures():
    cfg = load_config(None)
    assert (cfg.min_focus_s, cfg.max_focus_s, cfg.switch_lead, cfg.confirm_s, cfg.lost_grace_s) == (4, 8, 0.12, 0.8,
                                                                                                      0.8)
    assert (cfg.max_speed_deg_s, cfg.idle_s, cfg.glance_interval_s, cfg.rate_hz) == (60, 5, 5, 10)


def test_a_bad_configuration_is_refused_by_name(tmp_path):
    bad = tmp_path / "attention.yaml"
    bad.write_text("min_focus_s: 9\nmax_focus_s: 8\n")
    with pytest.raises(ValueError, match=r"attention\.yaml.*min_focus_s must not exceed max_focus_s"):
        load_config(bad)
    bad.write_text("max_speed: 30\n")
    with pytest.raises(ValueError, match="max_speed"):
        load_config(bad)


def test_luxais_score_weighs_facing_proximity_and_voice():
    assert score(Candidate("a", 0, distance=1.5, facing=1.0), CFG) == pytest.approx(0.6 + 0.4 * 0.5)
    assert score(Candidate("a", 0, distance=1.5, facing=1.0, speaking_since=0.0), CFG) == pytest.approx(
        0.5 + 0.3 * 0.5 + 0.2)
    assert score(Candidate("a", 0, distance=3.5), CFG) is None and score(Candidate("a", 0, distance=0.2), CFG) is None


def test_a_speaker_away_from_the_focus_takes_it_after_the_confirmation_whatever_the_minimum_focus():
    att = Attention(CFG)
    att.reset((0.0, 0.0))
    left, right = Candidate("left", 20.0, distance=1.5), Candidate("right", -25.0, distance=1.5)
    run(att, 0.0, 1.0, lambda now: [left, right])
    first = att.focus
    other = right if first == "left" else left
    speaking = Candidate(other.key, other.yaw, distance=1.5, speaking_since=1.05)
    trace = run(att, 1.0, 3.0, lambda now: [left if first == "left" else right, speaking])
    switched = next(now for now, t in trace if att.focus and t.key == other.key)
    assert 1.05 + CFG.confirm_s <= switched + 1e-9 <= 1.05 + CFG.confirm_s + DT + 1e-9  # well inside min focus
    # then the head turns at its speed limit until it points at the speaker
    arrive = next(now for now, t in trace if abs(t.yaw - other.yaw) < 1e-6)
    assert arrive - switched >= abs(other.yaw - (20.0 if first == "left" else -25.0)) / CFG.max_speed_deg_s - DT


def test_a_better_face_waits_for_the_minimum_focus_and_a_held_lead():
    att = Attention(CFG)
    att.reset((0.0, 0.0))
    a = Candidate("a", 10.0, distance=2.5, facing=0.6)
    run(att, 0.0, 0.5, lambda now: [a])
    assert att.focus == "a"
    b = Candidate("b", -10.0, distance=1.0, facing=1.0)  # leads by far more than 0.12
    trace = run(att, 0.5, 6.0, lambda now: [a, b])
    switched = next(now for now, t in trace if t.key == "b")
    assert switched >= 0.1 + CFG.min_focus_s + CFG.confirm_s - 1e-9


def test_a_focus_lost_for_less_than_the_grace_is_kept_and_longer_is_dropped():
    att = Attention(CFG)
    att.reset((0.0, 0.0))
    a, b = Candidate("a", 10.0, distance=1.0), Candidate("b", -10.0, distance=2.9, facing=0.2)
    run(att, 0.0, 0.5, lambda now: [a, b])
    assert att.focus == "a"
    run(att, 0.5, CFG.lost_grace_s - 2 * DT, lambda now: [b])
    assert att.focus == "a"
    run(att, 0.5 + CFG.lost_grace_s - 2 * DT, 3 * DT, lambda now: [b])
    assert att.focus == "b"


def test_with_nobody_there_the_robot_glances_around_every_few_seconds():
    att = Attention(CFG, seed=3)
    att.reset((0.0, 0.0))
    trace = run(att, 0.0, 16.0, lambda now: [])
    glances = [now for now, t in trace if t is not None]
    assert glances and glances[0] == pytest.approx(DT + CFG.idle_s)  # nobody seen since the first tick
    assert all(t.source == "glance" for _, t in trace if t is not None)
    # a new point every glance_interval_s: where the head has settled before each next glance differs
    settled = [t.yaw for now, t in trace if t is not None and any(abs(now - k) < 1e-6 for k in (10.0, 15.0))]
    assert len(settled) == 2 and abs(settled[0] - settled[1]) > 1e-3
    bound = math.degrees(math.atan2(CFG.glance_y_m, CFG.glance_x_m))
    assert all(abs(t.yaw) <= bound + 1e-6 for _, t in trace if t is not None)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-120, 120), st.floats(-60, 60), st.floats(0.2, 4.0), st.booleans()),
                min_size=0, max_size=4), st.integers(0, 2**16))
def test_the_head_never_leaves_its_limits_nor_turns_faster_than_the_limit(people, seed):
    att = Attention(CFG, yaw_limits=(-60.0, 60.0), pitch_limits=(-15.0, 25.0), seed=seed)
    att.reset((0.0, 0.0))
    cands = [Candidate(f"p{i}", y, p, d, 1.0, 0.0 if s else None) for i, (y, p, d, s) in enumerate(people)]
    last = (0.0, 0.0)
    for now, t in run(att, 0.0, 12.0, lambda now: cands[: int(now) % (len(cands) + 1)]):
        if t is None:
            continue
        assert -60.0 <= t.yaw <= 60.0 and -15.0 <= t.pitch <= 25.0
        assert math.hypot(t.yaw - last[0], t.pitch - last[1]) <= CFG.max_speed_deg_s * DT + 1e-6
        last = (t.yaw, t.pitch)


def test_ownership_gives_the_strongest_claimant_and_an_older_gestures_end_keeps_a_newer_claim():
    owners = Ownership((Part.HEAD, Part.RIGHT_ARM, Part.LEFT_ARM))
    seen = []
    owners.changed.append(lambda: seen.append(owners.owner(Part.HEAD)))
    owners.claim(Owner.GESTURE, [Part.HEAD], "nod#1")
    owners.claim(Owner.GESTURE, [Part.HEAD], "nod#2")
    owners.release(Owner.GESTURE, [Part.HEAD], "nod#1")
    assert owners.owner(Part.HEAD) == Owner.GESTURE and owners.holder(Part.HEAD) == "nod#2"
    owners.claim(Owner.OPERATOR, [Part.HEAD], "op-1")
    assert owners.owner(Part.HEAD) == Owner.OPERATOR and owners.free(Part.RIGHT_ARM)
    owners.release(Owner.OPERATOR)
    owners.release(Owner.GESTURE, [Part.HEAD], "nod#2")
    assert owners.free(Part.HEAD) and seen[-1] == Owner.NONE
    with pytest.raises(ValueError, match="claimant"):
        owners.claim(Owner.AUTONOMY, [Part.HEAD])
    with pytest.raises(KeyError, match="parts are"):
        owners.claim(Owner.TRIAL, ["tail"])


def test_the_packaged_rules_load_and_name_menu_items(tmp_path):
    rules = load_rules(None)
    assert rules.timeout_s == 6.0 and rules.on_timeout == "execute"
    assert {r.when for r in rules.rules} == {"speech_ended", "silence", "new_face", "looked_away"}
    with pytest.raises(ValueError, match=r"rules\.yaml: no menu item for praise -> speech\.sentences\.well_done"):
        check_actions(rules, {"emotion.happy"}, None)


@pytest.mark.parametrize("text, problem", [
    ("rules:\n  - {id: a, when: sneeze, action: emotion.happy, reason: r}\n", "when"),
    ("rules:\n  - {id: a, when: silence, action: emotion.happy}\n", "reason"),
    ("timeout_s: -1\n", "timeout_s"),
    ("rules:\n  - {id: a, when: silence, action: x, reason: r}\n  - {id: a, when: silence, action: y, reason: r}\n",
     "unique"),
    ("on_timeout: explode\n", "on_timeout"),
    ("rules: [\n", "rules.yaml"),
])
def test_bad_rules_are_refused_by_name(tmp_path, text, problem):
    path = tmp_path / "rules.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=problem) as info:
        load_rules(path)
    assert str(path) in str(info.value)


def test_the_learner_forbids_and_learns_the_teachers_repeated_action_and_keeps_it(tmp_path):
    path = tmp_path / "memory.json"
    learner = Learner(path)
    spoke, silent = Situation("speech_ended"), Situation("silence")
    learner.record(spoke, "emotion.happy", Outcome.FORBIDDEN)
    assert learner.forbidden(spoke, "emotion.happy") and not learner.forbidden(silent, "emotion.happy")
    learner.record(spoke, "speech.sentences.well_done", Outcome.TEACHER_INITIATED)
    assert learner.learned(spoke) == []
    learner.record(spoke, "speech.sentences.well_done", Outcome.TEACHER_INITIATED)
    assert [a for a, _ in learner.learned(spoke)] == ["speech.sentences.well_done"] and learner.learned(silent) == []
    assert not learner.record(spoke, "emotion.sad", Outcome.SUPERSEDED)  # teaches nothing
    assert learner.confidence(spoke, "speech.sentences.well_done", 0.5) > 0.5
    learner.save()
    again = Learner(path)
    assert again.forbidden(spoke, "emotion.happy") and [a for a, _ in again.learned(spoke)] == [
        "speech.sentences.well_done"]
    assert json.loads(path.read_text())["version"] == 1


@pytest.mark.parametrize("content", ["{not json", '{"version": 1, "points": [{"situation": "x"}]}',
                                     '{"version": 7, "points": []}',
                                     '{"version": 1, "points": [{"situation": "s", "action": "a", "outcome": '
                                     '"maybe", "reward": 1}]}'])
def test_a_bad_memory_file_is_refused_by_name(tmp_path, content):
    path = tmp_path / "memory.json"
    path.write_text(content)
    with pytest.raises(ValueError, match="autonomy memory") as info:
        Learner(path)
    assert str(path) in str(info.value)


def test_a_clients_hold_lasts_while_it_commands_and_its_grace_after():
    """Ownership.hold: a command claims its parts at once; after it ends they stay the client's for the grace,
    renewed by a command in between (a script's pause), then are free; a stronger claimant still wins meanwhile."""
    import asyncio

    async def main() -> list[tuple[Owner, Owner]]:
        owners = Ownership((Part.HEAD, Part.RIGHT_ARM, Part.LEFT_ARM))
        assert {Part.VOICE, Part.FACE} <= set(owners.parts)
        loop = asyncio.get_running_loop()
        seen: list[tuple[Owner, Owner]] = []
        grace_over = loop.create_future()
        owners.changed.append(lambda: seen.append((owners.owner(Part.HEAD), owners.owner(Part.VOICE))))
        owners.changed.append(lambda: owners.free(Part.VOICE) and not grace_over.done()
                              and grace_over.set_result(None))
        saying = owners.hold(Owner.CLIENT, [Part.VOICE], "script", 0.05)  # a sentence runs
        owners.hold(Owner.CLIENT, [Part.HEAD], "script", 0.05)()  # a head command: instant
        owners.claim(Owner.OPERATOR, [Part.HEAD], "op")
        assert owners.owner(Part.HEAD) == Owner.OPERATOR and owners.holder(Part.VOICE) == "script"
        owners.release(Owner.OPERATOR)
        saying()
        saying()  # ending twice is ending once
        owners.hold(Owner.CLIENT, [Part.VOICE], "script", 0.05)()  # the next sentence within the grace renews it
        await grace_over
        return seen

    seen = asyncio.run(main())
    assert seen[0] == (Owner.NONE, Owner.CLIENT) and (Owner.OPERATOR, Owner.CLIENT) in seen
    assert seen[-1] == (Owner.NONE, Owner.NONE)  # after the graces, both free


def test_a_motivation_variable_at_rest_is_never_coloured():
    """Fatigue rests at 0, under its low limit 15: at rest it reads ok (nothing to act on); a limit away from the
    rest value (curiosity's high 80) still counts."""
    from vr_teleop_server.core.bus import Bus
    from vr_teleop_server.core.events import declare_event_topic
    from client_protocol.registry import TypeRegistry
    from vr_teleop_server.features.motivation import Motivation

    from client_protocol import names

    bus = Bus(TypeRegistry())
    declare_event_topic(bus)
    bus.declare_topic(names.MOTIVATION_STATUS_TOPIC, "vr_teleop_msgs/Motivation")
    motivation = Motivation(bus)
    levels = dict(zip(motivation.message()["name"], motivation.message()["level"]))
    assert levels["fatigue"] == "ok" and motivation.values["fatigue"] == 0
    motivation._change("curiosity", 85)
    assert dict(zip(motivation.message()["name"], motivation.message()["level"]))["curiosity"] == "high"
