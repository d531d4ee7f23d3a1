"""Motor temperatures for the stand-in's motor status (it has no sensors): modelled, not measured.

Each motor warms with the square of its torque and cools toward ambient, a first-order lag: at a steady torque f
it settles at ambient + GAIN * f^2 with time constant TAU_S.
"""

from __future__ import annotations

import numpy as np


class ThermalModel:
    GAIN = 0.02  # K above ambient per (N m)^2 of steady torque
    TAU_S = 120.0
    EVERY_STEPS = 50  # physics steps between updates (0.1 s at 2 ms)

    def __init__(self, motors: int, ambient_c: float) -> None:
        self.ambient = float(ambient_c)
        self.temperature = np.full(motors, self.ambient)

    def update(self, torques: np.ndarray, seconds: float) -> None:
        """Advance by `seconds` at these torques (N m, one per motor)."""
        self.temperature += (self.ambient + self.GAIN * torques * torques - self.temperature) * (seconds / self.TAU_S)
