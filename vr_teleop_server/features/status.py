"""The status panels of the status menu, published at 2 Hz as typed messages on /vr_teleop/status/*.

hardware: the server machine's CPU, memory and (where the kernel reports one) temperature, via psutil.
robot_hardware: the robot's own, as its backend reports it (Robot.hardware_report): what it cannot read is named.
motors: each motor once, with its position normalised to its own joint range, temperature, voltage and mode.
dialog: the newest vr_teleop_msgs/DialogState a dialog system published on /vr_teleop/dialog/update.
motivation: published by the motivation variables themselves (motivation.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from typing import Any

import psutil

from client_protocol import names

from ..core.bus import SERVER_NODE, Bus, Published
from ..core.tasks import cancel_and_wait
from ..robot.interface import MotorMode, Robot

RATE_HZ = 2.0
MODE_NAMES = {MotorMode.ON: "on", MotorMode.OFF: "off", MotorMode.BRAKE: "brake"}


def _temperature() -> float | None:
    read = getattr(psutil, "sensors_temperatures", None)
    if read is None:
        return None
    with contextlib.suppress(OSError, RuntimeError):
        readings = [t.current for sensors in read().values() for t in sensors if t.current is not None]
        if readings:
            return float(max(readings))
    return None


class StatusPublisher:
    def __init__(self, bus: Bus, robot: Robot) -> None:
        self.bus = bus
        self.robot = robot
        self._dialog: dict[str, Any] = {"question": "", "mode": "", "answer": "", "candidates": [],
                                        "optionals": [], "chosen": ""}
        self._task: asyncio.Task[None] | None = None
        self._process = psutil.Process()

    def start(self) -> None:
        bus = self.bus
        bus.declare_topic(names.HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/HardwareStatus", persistent=True)
        bus.declare_topic(names.MOTORS_STATUS_TOPIC, "vr_teleop_msgs/MotorsStatus", persistent=True)
        bus.declare_topic(names.ROBOT_HARDWARE_STATUS_TOPIC, "vr_teleop_msgs/RobotHardwareStatus", persistent=True)
        bus.declare_topic(names.DIALOG_STATUS_TOPIC, "vr_teleop_msgs/DialogState", persistent=True)
        bus.declare_topic(names.DIALOG_UPDATE_TOPIC, "vr_teleop_msgs/DialogState", persistent=True)
        bus.subscribe(SERVER_NODE, names.DIALOG_UPDATE_TOPIC, None, self._on_dialog)
        psutil.cpu_percent(None)  # the first reading is meaningless; prime it
        self._task = asyncio.ensure_future(self._run())

    async def stop(self) -> None:
        task, self._task = self._task, None
        await cancel_and_wait(task)

    def _on_dialog(self, published: Published) -> None:
        value = {k: v for k, v in published.data.items() if k != "header"}
        self._dialog = value
        self.bus.publish(names.DIALOG_STATUS_TOPIC, self.dialog())

    async def _run(self) -> None:
        while True:
            self.publish_all()
            await asyncio.sleep(1.0 / RATE_HZ)

    def publish_all(self) -> None:
        self.bus.publish(names.HARDWARE_STATUS_TOPIC, self.hardware())
        self.bus.publish(names.ROBOT_HARDWARE_STATUS_TOPIC, self.robot_hardware())
        self.bus.publish(names.MOTORS_STATUS_TOPIC, self.motors())
        self.bus.publish(names.DIALOG_STATUS_TOPIC, self.dialog())

    def _header(self) -> dict[str, Any]:
        return {"stamp": self.bus.registry.now()}

    def hardware(self) -> dict[str, Any]:
        memory = psutil.virtual_memory()
        temperature = _temperature()
        return {"header": self._header(), "cpu_percent": psutil.cpu_percent(None),
                "memory_percent": memory.percent, "memory_used_mb": (memory.total - memory.available) / 2**20,
                "has_temperature": temperature is not None, "temperature_c": temperature or 0.0,
                "load_1min": os.getloadavg()[0]}

    def robot_hardware(self) -> dict[str, Any]:
        r = self.robot.hardware_report()
        figures = {"motor_temperature": r.motor_temperature_c, "motor_voltage": r.motor_voltage_min_v,
                   "battery": r.battery_percent, "cpu": r.cpu_percent, "memory": r.memory_percent,
                   "temperature": r.temperature_c}
        return {"header": self._header(), "backend": self.robot.backend, "source": r.source,
                "connected": r.connected, "motors": r.motors, "hottest_motor": r.hottest_motor,
                "motor_temperature_c": r.motor_temperature_c or 0.0,
                "motor_voltage_min_v": r.motor_voltage_min_v or 0.0, "motor_faults": r.motor_faults, "battery_percent": r.battery_percent or 0.0,
                "cpu_percent": r.cpu_percent or 0.0, "memory_percent": r.memory_percent or 0.0,
                "temperature_c": r.temperature_c or 0.0,
                **{f"has_{name}": value is not None for name, value in figures.items()},
                "missing": list(r.missing), "missing_reason": list(r.missing.values())}

    def motors(self) -> dict[str, Any]:
        model = self.robot.model
        motors = self.robot.motor_status()
        normalized = []
        for m in motors:
            joint = model.joint(m.name)
            normalized.append(min(1.0, max(0.0, (m.position - joint.lower) / (joint.upper - joint.lower))))
        return {"header": self._header(), "name": [m.name for m in motors],
                "position": [m.position for m in motors], "position_normalized": normalized,
                "temperature": [m.temperature_c if m.temperature_c is not None else 0.0 for m in motors],
                "voltage": [m.voltage_v if m.voltage_v is not None else 0.0 for m in motors],
                "mode": [MODE_NAMES.get(m.mode, str(m.mode)) for m in motors], "fault": [m.fault for m in motors]}

    def dialog(self) -> dict[str, Any]:
        return {"header": self._header(), **self._dialog}
