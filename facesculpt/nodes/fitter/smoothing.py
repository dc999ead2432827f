"""One Euro filter (Casiez, Roussel & Vogel, CHI 2012) for arrays of any shape.

A first-order low-pass whose cutoff rises with the signal's speed: a still face is smoothed hard
(cutoff ``min_cutoff`` Hz — no jitter), a moving one follows with little lag (cutoff grows by
``beta`` per unit/s of the smoothed derivative). Per element:

    τ = 1 / (2π f_c),  a = 1 / (1 + τ / T_e),  x̂ ← x̂ + a (x − x̂),  f_c = min_cutoff + beta · |dx̂/dt|

with the derivative itself low-passed at ``d_cutoff`` Hz.
"""

from __future__ import annotations

import numpy as np


def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray:
    tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff, np.float64))
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """One Euro filter over a fixed-shape array. ``min_cutoff`` Hz, ``beta`` (Hz per unit/s),
    ``d_cutoff`` Hz; ``predict_speed`` (units/s, 0: off): each step starts from the last output
    moved on at the smoothed velocity, weighed by speed² / (speed² + predict_speed²), so a signal
    at constant speed is followed without lag while a still one is filtered as without it. Call with the value and its time in seconds; returns the filtered value."""

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.05, d_cutoff: float = 1.0, predict_speed: float = 0.0):
        if min_cutoff <= 0 or d_cutoff <= 0 or beta < 0:
            raise ValueError("One Euro filter needs min_cutoff > 0, d_cutoff > 0, beta >= 0")
        self.min_cutoff = float(min_cutoff)
        self.beta = float(beta)
        self.d_cutoff = float(d_cutoff)
        self.predict_speed = float(predict_speed)
        self.reset()

    def reset(self) -> None:
        self._x: np.ndarray | None = None
        self._dx: np.ndarray | None = None
        self._t: float | None = None

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if self._x is None or self._x.shape != x.shape or self._t is None or t <= self._t:
            if self._x is not None and self._x.shape == x.shape and self._t is not None and t <= self._t:
                return self._x.copy()  # repeated or out-of-order time: keep the last output
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), float(t)
            return x.copy()
        dt = float(t) - self._t
        dx = (x - self._x) / dt
        self._dx = self._dx + _alpha(self.d_cutoff, dt) * (dx - self._dx)
        cutoff = self.min_cutoff + self.beta * np.abs(self._dx)
        base = self._x
        if self.predict_speed > 0:  # constant velocity, weighed in as the speed clears predict_speed
            speed2 = self._dx ** 2
            base = self._x + speed2 / (speed2 + self.predict_speed ** 2) * self._dx * dt
        self._x = base + _alpha(cutoff, dt) * (x - base)
        self._t = float(t)
        return self._x.copy()

    def hold(self, x: np.ndarray) -> None:
        """Make ``x`` the last output (a bound applied to it outside): the next step starts from
        there. Nothing happens before the first value."""
        if self._x is not None:
            self._x = np.asarray(x, np.float64).reshape(self._x.shape).copy()
