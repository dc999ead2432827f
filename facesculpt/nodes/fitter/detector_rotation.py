"""The head's rotation as the landmark network's own 3D points give it: a prior for a sparse fit's pose.

Fitted to 68 points in the image, a morphable model finds the head's pitch poorly: a nod moves
the nose against the eyes by a few pixels, which the expression and the landmarks' own
pose-dependent errors can mimic, and the fitted pitch follows a nod only part of the way. The
face-mesh network gives every point a relative depth too, and its 3D points follow the head's
rotation from frame to frame closely. Aligned (similarity Procrustes) to a reference of the same
points, learned over the first frames in the network's head frame, they give the rotation in
that frame. Where that frame lies against the model's is left to the landmarks: the offset is the
running chordal mean of (network rotation)ᵀ (landmark-only rotation) over the frames (a long,
fading window), so over time the fit keeps the landmarks' mean pose and takes its changes from
the network. (Aligning the model's own points to the reference instead gave the offset from the
two shapes alone: right on a synthetic Surrey head, up to 10 degrees of pitch off the landmarks
and the appearance refinement on a real face.) The prior is (network rotation) (offset).

The first frames are fitted before the person's identity is learned (the model's mean face, then
an identity still moving), and their landmark-only rotations are off by several degrees of pitch
that the long window would keep. So the frames learned until the fit calls
:meth:`~DetectorRotation.relearn` keep what their rotation was fitted from (the ``record`` given
to :meth:`~DetectorRotation.learn`, the fitter's own); once the identity has settled the fitter
fits those rotations again with it, and ``relearn`` swaps each frame's term of the fading mean for
the new one, at its own weight. Until then the prior holds with the offsets as learned.

Arrays in, arrays out: :class:`DetectorRotation` keeps the reference and the offset;
:meth:`~DetectorRotation.observe` takes a frame's points, :meth:`~DetectorRotation.prior` gives the
prior, :meth:`~DetectorRotation.learn` takes the frame's landmark-only rotation,
:meth:`~DetectorRotation.relearn` the kept frames' rotations fitted again.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry import similarity
from facesculpt.nodes.fitter.pose import nearest_rotation, rodrigues, rotation_log

#: The iBUG-68 landmark ids (1-based names) whose depth is used: the nose (bridge and base) and
#: the eyes' corners, which expressions barely move (the brows, lids and mouth do, and the jaw's
#: points lie on the silhouette, which slides over the face as it turns).
RIGID_IDS = tuple(str(i) for i in (*range(28, 37), 37, 40, 43, 46))
#: The fading window (frames) of the offset's mean: long against a nod, so the landmarks' errors
#: that follow the pose average out.
OFFSET_FRAMES = 300.0


class DetectorRotation:
    """The network's rotation of the head, in the model's head frame.

    reference_frames (>= 1): frames averaged into the reference of the network's 3D points, and
    offsets learned before a prior is given; offset_frames (> 0): the fading window (frames) of
    the offset's mean; settle_frames (>= 0): the first frames' offsets are not learned (fitted
    before the person's identity is, their landmark-only pitch is biased, and the fading mean
    would keep that bias for hundreds of frames); gain (3,) or None: the network's rotation from
    its reference, as a rotation vector in camera axes (x: pitch, y: yaw, z: roll), is multiplied by it (a network whose points
    turn by 1/gain of the head: the model's calibration, :mod:`.calibration`); keep_frames (>= 0;
    0: none): the most frames whose records are kept until :meth:`relearn` (the first ones)."""

    def __init__(self, reference_frames: int = 30, offset_frames: float = OFFSET_FRAMES, gain=None,
                 settle_frames: int = 0, keep_frames: int = 0):
        self.reference_frames = int(reference_frames)
        self.settle_frames = int(settle_frames)
        self.keep_frames = int(keep_frames)
        self.gain = None if gain is None or not len(gain) else np.asarray(gain, np.float64).reshape(3)
        self.decay = 1.0 - 1.0 / float(offset_frames)
        self.reset()

    def reset(self) -> None:
        """Forget the reference and the offset (another face, or a cold start)."""
        self.reference: np.ndarray | None = None   # (P, 3) the network's head frame, px
        self.reference_count = 0
        self._offset_sum = np.zeros((3, 3))
        self.offsets_learned = 0
        self.offsets_offered = 0
        # (index in the fading mean, R_network, R_landmarks, record) of the frames learned before
        # the relearning; None once relearned
        self._kept: list | None = []

    def observe(self, points: np.ndarray) -> np.ndarray | None:
        """The network's rotation (3, 3) of this frame's head (camera axes: x right, y down, z
        away) from its rigid points (:data:`RIGID_IDS`) ``points`` (P, 3) px (x, y image pixels, z
        relative depth in pixels, nearer smaller), in the reference's order; None when a point is
        not finite. The first ``reference_frames`` frames are averaged into the reference."""
        points = np.asarray(points, np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            return None
        if self.reference is None or self.reference.shape != points.shape:
            self.reset()
            self.reference, self.reference_count = points - points.mean(0), 1
            return np.eye(3)
        try:
            s, R, t = similarity.similarity_procrustes(self.reference, points)
        except ValueError:
            return None
        if self.reference_count < self.reference_frames:
            local = (points - t) @ R / s
            n = self.reference_count
            self.reference = (self.reference * n + local) / (n + 1)
            self.reference_count = n + 1
        return R if self.gain is None else rodrigues(self.gain * rotation_log(R))

    def prior(self, R_network: np.ndarray | None) -> np.ndarray | None:
        """The prior (3, 3) on the model's rotation for the network's rotation ``R_network``;
        None until enough offsets were learned (or without ``R_network``)."""
        if R_network is None or self.offsets_learned < self.reference_frames:
            return None
        return R_network @ nearest_rotation(self._offset_sum)

    def learn(self, R_network: np.ndarray | None, R_landmarks: np.ndarray, record=None) -> None:
        """Add one frame's offset: the network's rotation and the rotation (3, 3) fitted to the
        landmarks alone (without the prior); ``record`` (the fitter's, anything): what that rotation
        was fitted from, kept for :meth:`relearn` (the first ``keep_frames`` frames until then)."""
        if R_network is None:
            return
        self.offsets_offered += 1
        if self.offsets_offered <= self.settle_frames:   # the landmark fit's identity is still settling
            return
        R_network = np.asarray(R_network, np.float64)
        R_landmarks = np.asarray(R_landmarks, np.float64)
        self._offset_sum = self.decay * self._offset_sum + R_network.T @ R_landmarks
        if record is not None and self._kept is not None and len(self._kept) < self.keep_frames:
            self._kept.append((self.offsets_learned, R_network, R_landmarks, record))
        self.offsets_learned += 1

    @property
    def kept(self) -> list:
        """The records of the frames kept for :meth:`relearn`, oldest first ([] once relearned)."""
        return [] if self._kept is None else [k[3] for k in self._kept]

    @property
    def relearned(self) -> bool:
        """Whether :meth:`relearn` was called since the last :meth:`reset`."""
        return self._kept is None

    def relearn(self, R_landmarks) -> None:
        """Each kept frame's landmark-only rotation fitted again (a sequence of (3, 3), one per
        :attr:`kept` record, in its order): its term of the offset's fading mean is swapped for
        the new one at the weight the frame has now. Once only: the records are dropped, and the
        frames learned from now on are not kept."""
        kept, self._kept = self._kept or [], None
        if len(R_landmarks) != len(kept):
            raise ValueError(f"relearn needs one rotation per kept frame ({len(kept)}), got {len(R_landmarks)}")
        for (index, R_network, R_old, _), R_new in zip(kept, R_landmarks):
            weight = self.decay ** (self.offsets_learned - 1 - index)
            self._offset_sum += weight * R_network.T @ (np.asarray(R_new, np.float64) - R_old)
