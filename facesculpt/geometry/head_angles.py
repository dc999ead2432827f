"""Head yaw, pitch and roll of a model-to-camera rotation, and back.

Model space: x toward the subject's left, y up, z out of the face; camera space OpenCV's (x right,
y down, z away from the camera). A face looking into the camera has ``R = FRONTAL``.
"""

from __future__ import annotations

import numpy as np

FRONTAL = np.diag([1.0, -1.0, -1.0])


def euler_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """Head yaw, pitch, roll in degrees of a model-to-camera rotation, relative to the frontal pose
    (``R = FRONTAL · Rz(roll) · Rx(pitch) · Ry(yaw)``, angles about the model's y, x, z axes)."""
    M = FRONTAL.T @ np.asarray(R, np.float64)  # = Rz(roll) Rx(pitch) Ry(yaw)
    yaw = np.degrees(np.arctan2(-M[2, 0], M[2, 2]))
    pitch = np.degrees(np.arcsin(np.clip(M[2, 1], -1, 1)))
    roll = np.degrees(np.arctan2(-M[0, 1], M[1, 1]))
    return float(yaw), float(pitch), float(roll)


def rotation_from_euler(yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """Model-to-camera rotation for a head turned by yaw (about y), pitch (about x), roll (about z),
    degrees, starting from the frontal pose; the inverse of :func:`euler_from_rotation`."""
    y, p, r = np.radians([yaw, pitch, roll])
    Ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return FRONTAL @ (Rz @ Rx @ Ry)
