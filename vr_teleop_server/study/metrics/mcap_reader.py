"""A trial's state updates, interventions and window from a session recording (MCAP, as `serve --record` and
`vr-teleop study run` write it): the JSON channels /study/state_updates (vr_teleop_msgs/StateUpdate),
/study/interventions (vr_teleop_msgs/Intervention) and /study/trial (vr_teleop_msgs/TrialState).

A StateUpdate is published at its start and again at its stop with the same id; an id never stopped is an
unfinished action. The window is [0, elapsed of the trial's final state] (T0 is the trial's clock start); a
recording cut short has no final state, and its window is then left to the defaults (earliest start, latest
stop). Interventions are known (effectiveness computed) when the trial published a state, i.e. ran under the
study runner, which publishes every intervention.
"""

from __future__ import annotations

from pathlib import Path

from client_protocol import names

from ...recording.format import check_recording, read_recording

from .model import Intervention, MetricsInputError, StateUpdate, TrialData

FINAL_STATES = ("completed", "preempted", "failed")


def read_trial_mcap(path: Path | str, trial: str | None = None) -> TrialData:
    path = Path(path)
    if not path.is_file():
        raise MetricsInputError(path, "file not found", "check the path")
    starts: dict[tuple[str, int], dict] = {}
    stops: dict[tuple[str, int], float] = {}
    interventions: dict[str, list[Intervention]] = {}
    states: dict[str, dict] = {}
    try:
        for m in read_recording(path):
            if m.topic == names.STUDY_STATE_UPDATES_TOPIC:
                key = (m.data["trial"], int(m.data["id"]))
                if m.data["finished"]:
                    stops[key] = float(m.data["stop"])
                starts.setdefault(key, m.data)
            elif m.topic == names.STUDY_INTERVENTIONS_TOPIC:
                d = m.data
                interventions.setdefault(d["trial"], []).append(Intervention(
                    start=float(d["start"]), stop=float(d["stop"]), subtask=d["subtask"] or None, note=d["note"]))
            elif m.topic == names.STUDY_TRIAL_TOPIC:
                states[m.data["trial"]] = m.data
    except (KeyError, TypeError, ValueError) as exc:
        raise MetricsInputError(path, f"a study message does not have the expected fields ({exc})",
                                "record with this version of vr-teleop") from None
    except OSError as exc:  # e.g. a file too short to hold an MCAP footer
        raise MetricsInputError(path, f"cannot read the recording ({exc.strerror or exc})",
                                "pass an MCAP file written by `vr-teleop serve --record` or `study run`") from None
    trials = sorted({k[0] for k in starts} | set(states))
    if not trials and not check_recording(path).closed:
        raise MetricsInputError(path, "cannot read the recording: it was cut off (never closed) before any study "
                                "state update", "pass an MCAP file written by `vr-teleop serve --record` or `study "
                                "run` and closed (Ctrl-C closes it)")
    if not trials:
        raise MetricsInputError(path, "the recording has no study state updates (/study/state_updates)",
                                "record a trial with `vr-teleop study run` or `serve --record` while a study runs")
    if trial is None:
        if len(trials) > 1:
            raise MetricsInputError(path, f"the recording holds several trials ({', '.join(trials)})",
                                    "choose one with --trial NAME")
        trial = trials[0]
    elif trial not in trials:
        raise MetricsInputError(path, f"no trial {trial!r} in the recording", f"use one of {', '.join(trials)}")
    updates = [StateUpdate(agent=d["agent"], action=d["action"], start=float(d["start"]), stop=stops.get(key))
               for key, d in starts.items() if key[0] == trial]
    state = states.get(trial)
    final = state is not None and state["state"] in FINAL_STATES
    return TrialData(updates=updates,
                     interventions=interventions.get(trial, []) if state is not None else None,
                     planned_subtasks=int(state["planned_subtasks"]) if state is not None else None,
                     t0=0.0 if final else None, t1=float(state["elapsed"]) if final else None)
