"""The renderer's pose edits (issue 18): the pose offset the deformer publishes for a face, plus
the renderer's own face-the-camera turn, applied to that face's deformed mesh.

A head turns about :func:`facesculpt.geometry.pose_offset.head_pivot` of its neutral. With
``face_camera`` above 0, each frame adds :func:`~facesculpt.geometry.pose_offset.face_camera_offset`
(that share of the way toward looking into the camera, at most ``limit_deg`` in yaw and pitch);
the direction to the camera (:func:`~facesculpt.geometry.pose_offset.camera_direction`, moved only
by the head's position) is smoothed per face over the frames' stamps (time constant
``FACE_CAMERA_SMOOTHING_S``), the head's own pose is not: its jitter then cancels in the turned
pose instead of passing through late. The
offline ``Pipeline`` does the same (``Pipeline._pose_edit``).
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.pose_offset import (
    FACE_CAMERA_LIMIT_DEG,
    FACE_CAMERA_LIMIT_RANGE,  # noqa: F401 (the renderer node's parameter range)
    FACE_CAMERA_SMOOTHING_S,
    PoseOffset,
    apply_pose_offset,
    camera_direction,
    face_camera_offset,
    head_pivot,
    smooth_values,
)
from facesculpt.msgs import FaceState


class PoseEdits:
    """Per face, the pose edit of each frame. ``face_camera``: 0-1 (0: off); ``limit_deg``: its
    largest turn in yaw and pitch, degrees."""

    def __init__(self, face_camera: float = 0.0, limit_deg: float = FACE_CAMERA_LIMIT_DEG,
                 time_constant_s: float = FACE_CAMERA_SMOOTHING_S):
        self.face_camera = float(face_camera)
        self.limit_deg = float(limit_deg)
        self.time_constant_s = float(time_constant_s)
        self._turns: dict[int, tuple[int, np.ndarray]] = {}  # face -> (frame stamp ns, smoothed direction to the camera)

    def edit(self, state: FaceState, pose: PoseOffset, neutral: np.ndarray, stamp_ns: int,
             face: int | None = None) -> tuple[PoseOffset, np.ndarray] | None:
        """The pose edit of ``state``'s face (``face``, default its ``face_id``) on the frame stamped
        ``stamp_ns``: (``pose`` plus the face-the-camera turn, the head's pivot (3,) model
        mm from ``neutral`` (V, 3) model mm); None when it is zero. ``state``: anything with the
        pose fields R, t, scale and projection (a FaceState, a fitter's FitResult)."""
        pivot = head_pivot(neutral)
        face = state.face_id if face is None else face
        if self.face_camera > 0:
            # the direction to the camera is smoothed, not the turn: the turned head then keeps none of
            # the tracked pose's jitter (all the way) or less of it, and does not lag behind the head
            perspective = state.projection == "perspective"
            direction = camera_direction(state.R, state.t, state.scale, pivot, perspective)
            last = self._turns.get(face)
            direction = smooth_values(None if last is None else last[1], direction,
                                      0.0 if last is None else (stamp_ns - last[0]) * 1e-9, self.time_constant_s)
            self._turns[face] = (int(stamp_ns), direction)
            pose = pose + face_camera_offset(state.R, state.t, state.scale, pivot, self.face_camera, self.limit_deg,
                                             to_camera=direction)
        return None if pose.is_zero else (pose, pivot)

    @staticmethod
    def apply(deformed: np.ndarray, state: FaceState, edit: tuple[PoseOffset, np.ndarray]) -> np.ndarray:
        """The (V, 3) camera-space ``deformed`` mesh of ``state``'s face turned and moved by
        ``edit`` (from :meth:`edit`)."""
        pose, pivot = edit
        return apply_pose_offset(deformed, state.R, state.t, state.scale, pivot, pose)
