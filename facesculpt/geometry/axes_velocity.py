"""Joystick axes to a model-space velocity: the one definition of that mapping and of its two
parameters (speed at full deflection, deadzone), which the joystick node and the deformer's
``axes`` events share."""

from __future__ import annotations

import numpy as np

# Defaults and valid ranges of the mapping's parameters (both nodes declare them from these).
SPEED_MM_S = 40.0
SPEED_MM_S_RANGE = (0.0, 1000.0)
DEADZONE = 0.1
DEADZONE_RANGE = (0.0, 0.99)


def axes_velocity(axes, speed_mm_s: float, deadzone: float = DEADZONE) -> np.ndarray:
    """Model-space velocity (3,) mm/s from joystick axes in -1..1 (A,).

    Axis 0 -> +x, axis 1 -> -y (stick pushed forward/up reads negative on most devices and
    should move the face point up, +y in model space), axis 2 -> +z (out of the face).
    Values inside ``deadzone`` read as 0; the rest is rescaled so the response starts at 0.
    """
    a = np.zeros(3)
    given = np.asarray(axes, dtype=np.float64).ravel()[:3]
    given = np.where(np.isfinite(given), given, 0.0)
    a[: given.size] = np.clip(given, -1.0, 1.0)
    mag = np.abs(a)
    a = np.where(mag > deadzone, np.sign(a) * (mag - deadzone) / max(1.0 - deadzone, 1e-9), 0.0)
    return float(speed_mm_s) * a * np.array([1.0, -1.0, 1.0])
