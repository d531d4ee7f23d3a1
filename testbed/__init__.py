"""The fakes and harnesses shared by the tests (tests/) and the benches (bench/): fake robots (a QTrobot v3 hub,
a ROS 1 robot's rosbridge), servers (server.py: in the caller's loop, in a thread, as a process, on free ports),
waiting for a condition, WebRTC and network-emulator helpers, the churn visitor. Both may import from here;
neither the server package nor the leaves may (tests/test_architecture.py), and bench/ imports nothing from tests/.
Not installed with the package: pytest finds it through pyproject's `pythonpath`, the benches through the
repository root on their path.

Importing it sets the environment the tests and benches run in, here and only here (ENVIRONMENT): MuJoCo reads
MUJOCO_GL when it is first imported, so tests/conftest.py and every bench import testbed before anything that
renders; the processes they start inherit it."""

from __future__ import annotations

import os

# MuJoCo's offscreen camera through EGL (Mesa's llvmpipe where there is no GPU), unless the caller chose another.
ENVIRONMENT = {"MUJOCO_GL": "egl"}

for _name, _value in ENVIRONMENT.items():
    os.environ.setdefault(_name, _value)
