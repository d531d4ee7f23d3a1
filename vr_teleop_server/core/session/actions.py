"""The action ops: goals the client sends, and goals of actions the client provides (forwarded to it)."""

from __future__ import annotations

import itertools
from typing import Any

from client_protocol import ops

from ..bus import GOAL_STATUS_ABORTED, Bus, BusError, GoalHandle
from .protocol import ProtocolError, json_value


class ActionOps:
    """Mixed into Session: its handlers of the action ops."""

    name: str
    bus: Bus
    actions: set[str]
    _goals_to_me: dict[str, GoalHandle]
    _my_goals: dict[Any, GoalHandle]
    _ids: itertools.count

    def _op_advertise_action(self, op: ops.AdvertiseAction) -> None:
        self.bus.advertise_action(self.name, op.action, op.type, ClientActionProvider(self))
        self.actions.add(op.action)

    def _op_unadvertise_action(self, op: ops.UnadvertiseAction) -> None:
        if op.action not in self.actions:
            raise ProtocolError(f"action {op.action} is not advertised by this client", "warning")
        self.actions.discard(op.action)
        self.bus.unadvertise_action(self.name, op.action)

    def _op_send_action_goal(self, op: ops.SendActionGoal) -> None:
        caller_id = op.id if op.id is not None else f"goal:{op.action}:{next(self._ids)}"
        if caller_id in self._my_goals:
            raise ProtocolError(f"a goal with id {caller_id!r} is already running")

        def on_feedback(values: Any) -> None:
            if op.feedback:
                self._reply({"op": "action_feedback", "id": caller_id, "action": op.action,
                             "values": json_value(values)}, op.compression, op.fragment_size, caller_id)

        def on_result(status: int, values: Any, result: bool) -> None:
            self._my_goals.pop(caller_id, None)
            self._reply({"op": "action_result", "id": caller_id, "action": op.action, "values": json_value(values),
                         "status": status, "result": result}, op.compression, op.fragment_size, caller_id)

        try:
            self._my_goals[caller_id] = self.bus.send_goal(op.action, op.action_type, op.args, on_feedback,
                                                           on_result)
        except BusError as exc:
            self._my_goals.pop(caller_id, None)
            on_result(GOAL_STATUS_ABORTED, str(exc), False)
            raise

    def _op_cancel_action_goal(self, op: ops.CancelActionGoal) -> None:
        goal = self._my_goals.get(op.id)
        if goal is None:
            raise ProtocolError(f"no goal with id {op.id!r} is running on {op.action}", "warning")
        self.bus.cancel_goal(goal)

    def _op_action_feedback(self, op: ops.ActionFeedback) -> None:
        goal = self._goals_to_me.get(str(op.id))
        if goal is None:
            raise ProtocolError(f"no goal with id {op.id!r} is being served by this client", "warning")
        goal.feedback(op.values)

    def _op_action_result(self, op: ops.ActionResult) -> None:
        goal = self._goals_to_me.pop(str(op.id), None)
        if goal is None:
            raise ProtocolError(f"no goal with id {op.id!r} is being served by this client", "warning")
        goal.finish(op.status, op.values, op.result)


class ClientActionProvider:
    """Serves an action's goals by forwarding them to the client that advertised it."""

    def __init__(self, session: ActionOps) -> None:
        self.session = session

    def start_goal(self, goal: GoalHandle) -> None:
        action = self.session.bus.actions[goal.action]
        self.session._goals_to_me[goal.goal_id] = goal
        self.session._send({"op": "send_action_goal", "id": goal.goal_id, "action": goal.action,
                            "action_type": action.type, "args": json_value(goal.args), "feedback": True})

    def cancel_goal(self, goal: GoalHandle) -> None:
        self.session._send({"op": "cancel_action_goal", "id": goal.goal_id, "action": goal.action})
