"""The robot avatar for Unity (ROS#): what its URDF importer and JointStatePatcher read.

- the `robot_description` parameter (rosapi's parameter server): QTrobot's URDF from robot_models;
- `/file_server/get_file` (file_server/GetBinaryFile): every `package://` resource the URDF names, and nothing
  outside the shipped packages. GetBinaryFile has no field for a refusal, so a refused name is answered with an
  empty `value` (what ROS#'s importer treats as a missing file), a status warning and a log line;
- `/joint_states` (sensor_msgs/JointState) at 30 Hz: the Robot interface's joint state in radians under the URDF's
  joint names, beside LuxAI's degrees topic. Degrees become radians here, at this one boundary.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from typing import Any

from client_protocol import names
from robot_models.urdf import PackageResourceError, resolve_package_uri, robot_description

from ..core.bus import Bus
from ..core.rosapi import RosApi
from ..core.tasks import cancel_and_wait, every
from ..robot.interface import Robot

log = logging.getLogger(__name__)

JOINT_STATES_RATE_HZ = 30.0


class Avatar:
    def __init__(self, bus: Bus, rosapi: RosApi, robot: Robot | None) -> None:
        self.bus = bus
        self.rosapi = rosapi
        self.robot = robot
        self._task: asyncio.Task[None] | None = None

    def start(self) -> None:
        # rosapi keeps parameter values as JSON text: the URDF is a JSON string
        self.rosapi.params[names.ROBOT_DESCRIPTION_PARAM] = json.dumps(robot_description())
        self.bus.provide(names.FILE_SERVER_SERVICE, "file_server/GetBinaryFile", self._get_file)
        if self.robot is not None:
            self.bus.declare_topic(names.URDF_JOINT_STATES_TOPIC, "sensor_msgs/JointState", persistent=True)
            self._task = asyncio.ensure_future(self._publish_joint_states())

    async def stop(self) -> None:
        task, self._task = self._task, None
        await cancel_and_wait(task)

    async def _get_file(self, request: Any) -> dict[str, Any]:
        caller = self.bus.caller()
        try:
            path = resolve_package_uri(request.name)
        except PackageResourceError as exc:
            log.warning("file_server: refused %s: %s", caller, exc)
            self.bus.report(caller, "warning", f"{names.FILE_SERVER_SERVICE}: refused: {exc}")
            return {"value": b""}
        return {"value": await asyncio.to_thread(path.read_bytes)}

    async def _publish_joint_states(self) -> None:
        robot = self.robot
        assert robot is not None
        order = robot.model.alphabetical_names

        def publish() -> None:
            state = robot.joint_state().reordered(order)
            secs = int(state.stamp_wall)
            self.bus.publish(names.URDF_JOINT_STATES_TOPIC, {
                "header": {"stamp": {"secs": secs, "nsecs": int((state.stamp_wall - secs) * 1e9)}},
                "name": list(state.names), "position": [math.radians(v) for v in state.positions],
                "velocity": [math.radians(v) for v in state.velocities], "effort": list(state.efforts)})

        await every(1.0 / JOINT_STATES_RATE_HZ, publish, "joint_states: publishing")  # a failed read: the next
