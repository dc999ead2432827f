"""Anderson acceleration of a fixed-point iteration (Peng et al., "Anderson Acceleration for
Geometry Optimization and Physics Simulation", SIGGRAPH 2018): the ARAP solver's local/global
step is such an iteration."""

from __future__ import annotations

import numpy as np


class AndersonAcceleration:
    """Anderson acceleration (type II, Walker & Ni 2011) of a fixed-point iteration x <- G(x) over
    the last ``depth`` steps: x_next = G(x) - dG gamma with gamma minimising |f - dF gamma|, where
    f = G(x) - x and the rows of dF, dG are differences of consecutive f and G(x). The differences
    live in a ring buffer and their Gram matrix is updated one row per step: a step costs a few
    vector operations on top of G."""

    # Extrapolations need weights well above 1, but a combination whose weights sum (in absolute
    # value) past this comes from a nearly degenerate history and lands far from the solution.
    MAX_WEIGHT = 20.0

    def __init__(self, depth: int):
        self.depth = depth
        self.dF: np.ndarray | None = None  # (depth, N) ring buffers
        self.dG: np.ndarray | None = None
        self.gram = np.zeros((depth, depth))
        self.size = 0
        self.head = 0
        self.f_prev: np.ndarray | None = None
        self.g_prev: np.ndarray | None = None

    def restart(self) -> None:
        """Forget the history."""
        self.size = self.head = 0
        self.f_prev = self.g_prev = None

    def begin_solve(self) -> None:
        """A new solve of the same map shifted (new handle positions): keep the history, but form
        no difference with the previous solve's last step."""
        self.f_prev = self.g_prev = None

    def step(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The next iterate from the current one ``x`` and its image ``g`` = G(x) (same shapes;
        ``g`` is kept, not copied: do not modify it afterwards)."""
        gf = g.reshape(-1)
        f = gf - x.reshape(-1)
        if self.f_prev is not None:
            if self.dF is None or self.dF.shape[1] != f.size:
                self.dF = np.empty((self.depth, f.size))
                self.dG = np.empty((self.depth, f.size))
            k = self.head
            np.subtract(f, self.f_prev, out=self.dF[k])
            np.subtract(gf, self.g_prev, out=self.dG[k])
            self.head = (k + 1) % self.depth
            self.size = min(self.size + 1, self.depth)
            column = self.dF[: self.size] @ self.dF[k]
            self.gram[k, : self.size] = column
            self.gram[: self.size, k] = column
        self.f_prev, self.g_prev = f, gf
        m = self.size
        if m == 0:
            return g
        A = self.gram[:m, :m].copy()
        # A tiny ridge keeps nearly collinear histories solvable.
        A[np.diag_indices_from(A)] += 1e-12 * max(float(np.trace(A)), 1e-300)
        try:
            gamma = np.linalg.solve(A, self.dF[:m] @ f)
        except np.linalg.LinAlgError:
            self.restart()
            return g
        if np.abs(gamma).sum() > self.MAX_WEIGHT:  # an ill-conditioned history: start it again
            self.restart()
            return g
        return (gf - gamma @ self.dG[:m]).reshape(g.shape)

