"""The fakes and harnesses shared by the tests (tests/) and the benches (bench/): fake robots (a QTrobot v3 hub,
a ROS 1 robot's rosbridge), a server in a thread of its own, WebRTC and network-emulator helpers, the churn visitor.
Both may import from here; neither the server package nor the leaves may (tests/test_architecture.py), and bench/
imports nothing from tests/. Not installed with the package: pytest finds it through pyproject's `pythonpath`, the
benches through the repository root on their path."""
