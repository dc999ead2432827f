"""A pose edit (issue 18): the head turned and moved by an offset on top of its tracked pose.

The offset's angles add to the head's own yaw, pitch and roll (:mod:`.head_angles`: a head at yaw
20° with ``yaw=10`` is drawn at yaw 30°); the head turns about a point ``HEAD_PIVOT_DEPTH_MM``
behind the nose tip, as a neck turns it. Its translation is in camera axes (mm: x right, y down,
z away from the camera). ``face_camera_offset`` is the offset that turns a face toward the camera: along :func:`camera_direction`, which only the
head's position moves (smooth that, not the turn: the head's own jitter then cancels in the turned
pose).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .head_angles import FRONTAL, euler_from_rotation, rotation_from_euler

#: The head turns about a point this far behind the nose tip (model space, mm).
HEAD_PIVOT_DEPTH_MM = 95.0
#: Largest angle (degrees, each of yaw, pitch, roll) a pose offset may have.
MAX_OFFSET_DEG = 45.0
#: Largest translation (mm, each axis) a pose offset may have.
MAX_OFFSET_MM = 200.0
#: The components of a pose offset, in the order messages carry them, and the limit of each.
OFFSET_NAMES = ("yaw", "pitch", "roll", "x", "y", "z")
OFFSET_LIMITS = (MAX_OFFSET_DEG,) * 3 + (MAX_OFFSET_MM,) * 3
#: Face-the-camera: its default largest turn (degrees, yaw and pitch each): the largest offset the
#: new-views benchmark measures (benchmarks/bench_new_views.py; docs/results/new-views.md).
FACE_CAMERA_LIMIT_DEG = 20.0
#: Face-the-camera: the range of that limit, degrees.
FACE_CAMERA_LIMIT_RANGE = (1.0, 45.0)
#: Face-the-camera: default time constant of the smoothing of the direction to the camera, s. None:
#: turned all the way each frame, the tracker's pose jitter cancels in the turned head, and any
#: smoothing of the fitted position only adds lag (docs/results/new-views.md).
FACE_CAMERA_SMOOTHING_S = 0.0
FACE_CAMERA_SMOOTHING_MAX_S = 60.0


@dataclass(frozen=True)
class PoseOffset:
    """yaw, pitch, roll: degrees added to the head's own angles; x, y, z: mm, camera axes."""

    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def __post_init__(self):
        for name, limit in zip(OFFSET_NAMES, OFFSET_LIMITS):
            value = getattr(self, name)
            if not (np.isfinite(value) and abs(value) <= limit):
                unit = "degrees" if limit == MAX_OFFSET_DEG else "mm"
                raise ValueError(f"pose {name} must be a number within ±{limit:g} {unit}, got {value}")

    @property
    def is_zero(self) -> bool:
        return not any(asdict(self).values())

    def as_list(self) -> list[float]:
        """[yaw, pitch, roll, x, y, z] (degrees, mm), as messages and presets carry it."""
        return [float(v) for v in asdict(self).values()]

    @classmethod
    def from_list(cls, values) -> PoseOffset:
        values = [float(v) for v in values]
        if len(values) != 6:
            raise ValueError(f"a pose offset has 6 values (yaw, pitch, roll, x, y, z), got {len(values)}")
        return cls(*values)

    @classmethod
    def clamped(cls, values) -> PoseOffset:
        """A PoseOffset from [yaw, pitch, roll, x, y, z] (degrees, mm), each clamped to its limit
        (OFFSET_LIMITS); ValueError when they are not 6 finite numbers."""
        v = np.asarray(values, np.float64).ravel()
        if v.shape != (6,) or not np.all(np.isfinite(v)):
            raise ValueError(f"a pose offset is 6 finite numbers, got {v.tolist()}")
        limits = np.array(OFFSET_LIMITS)
        return cls.from_list(np.clip(v, -limits, limits))

    def __add__(self, other: PoseOffset) -> PoseOffset:
        return PoseOffset.clamped(np.add(self.as_list(), other.as_list()))


def parse_pose_offset(text: str) -> PoseOffset:
    """``"yaw=10,pitch=-5"`` (any of yaw, pitch, roll in degrees, x, y, z in mm) -> PoseOffset.
    ValueError with one sentence on anything else."""
    names = list(OFFSET_NAMES)
    values = {}
    for part in str(text).split(","):
        if not part.strip():
            continue
        name, sep, value = part.partition("=")
        name = name.strip().lower()
        if not sep or name not in names:
            raise ValueError(f"a pose is NAME=VALUE pairs separated by commas with NAME one of "
                             f"{', '.join(names)} (e.g. yaw=10,pitch=-5), got {part.strip()!r}")
        try:
            values[name] = float(value)
        except ValueError:
            raise ValueError(f"pose {name} must be a number, got {value.strip()!r}") from None
    return PoseOffset(**values)


def check_face_camera(fraction: float, limit_deg: float, smoothing_s: float,
                      names: tuple[str, str, str] = ("face_camera", "face_camera_limit_deg", "face_camera_smoothing_s")) -> None:
    """ValueError in one sentence, naming the option by ``names``, unless the face-the-camera
    ``fraction`` is 0 to 1, ``limit_deg`` over 0 and at most MAX_OFFSET_DEG, and ``smoothing_s``
    0 to FACE_CAMERA_SMOOTHING_MAX_S."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"{names[0]} must be 0 to 1, got {fraction}")
    if not 0.0 < limit_deg <= MAX_OFFSET_DEG:
        raise ValueError(f"{names[1]} must be over 0 and at most {MAX_OFFSET_DEG:g} degrees, got {limit_deg}")
    if not 0.0 <= smoothing_s <= FACE_CAMERA_SMOOTHING_MAX_S:
        raise ValueError(f"{names[2]} must be 0 to {FACE_CAMERA_SMOOTHING_MAX_S:g} s, got {smoothing_s}")


def head_pivot(model_vertices: np.ndarray) -> np.ndarray:
    """(3,) float64 model mm: the point a head with these (V, 3) model-space vertices turns about:
    centred left-right and up-down on the face, ``HEAD_PIVOT_DEPTH_MM`` behind its foremost point."""
    V = np.asarray(model_vertices, np.float64).reshape(-1, 3)
    lo, hi = V.min(axis=0), V.max(axis=0)
    return np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), hi[2] - HEAD_PIVOT_DEPTH_MM])


def posed_rotation(R: np.ndarray, offset: PoseOffset) -> np.ndarray:
    """(3, 3) the model-to-camera rotation ``R`` with the offset's angles added to its own."""
    yaw, pitch, roll = euler_from_rotation(R)
    return rotation_from_euler(yaw + offset.yaw, pitch + offset.pitch, roll + offset.roll)


def apply_pose_offset(vertices: np.ndarray, R: np.ndarray, t: np.ndarray, scale: float,
                      pivot: np.ndarray, offset: PoseOffset) -> np.ndarray:
    """The head's (V, 3) camera-space ``vertices`` (of a pose ``camera = scale · R · model + t``:
    mm in perspective, pixel scale in orthographic) turned and moved by ``offset`` about ``pivot``
    (3,) model mm (:func:`head_pivot`). Returns (V, 3) in the dtype of ``vertices``."""
    X = np.asarray(vertices)
    if offset.is_zero:
        return X.copy()
    R = np.asarray(R, np.float64)
    centre = float(scale) * R @ np.asarray(pivot, np.float64) + np.asarray(t, np.float64)
    turn = posed_rotation(R, offset) @ R.T
    move = float(scale) * np.array([offset.x, offset.y, offset.z])
    out = (X.astype(np.float64) - centre) @ turn.T + centre + move
    return out.astype(X.dtype if np.issubdtype(X.dtype, np.floating) else np.float64)


def camera_direction(R: np.ndarray, t: np.ndarray, scale: float, pivot: np.ndarray,
                     perspective: bool = True) -> np.ndarray:
    """(3,) unit vector, camera space: from the pivot (3,) model mm of a head (pose R, t, scale as in
    :func:`apply_pose_offset`) to the camera (in orthographic, against the view axis)."""
    if not perspective:
        return np.array([0.0, 0.0, -1.0])
    centre = float(scale) * np.asarray(R, np.float64) @ np.asarray(pivot, np.float64) + np.asarray(t, np.float64)
    return -centre / max(np.linalg.norm(centre), 1e-9)


def facing_angles(R: np.ndarray, to_camera: np.ndarray) -> tuple[float, float]:
    """(yaw, pitch) degrees (:mod:`.head_angles`) at which a head of rotation ``R`` looks along
    ``to_camera`` (3,) camera space (:func:`camera_direction`), its roll kept."""
    roll = euler_from_rotation(R)[2]
    # the model's facing axis (+z) in camera space is R[:, 2] = FRONTAL · Rz Rx Ry · z; with roll
    # kept, solve Rx(pitch) Ry(yaw) z = (sin yaw, -sin pitch cos yaw, cos pitch cos yaw) = d
    Rz = FRONTAL @ rotation_from_euler(0.0, 0.0, roll)
    d = Rz.T @ FRONTAL @ (np.asarray(to_camera, np.float64) / max(np.linalg.norm(to_camera), 1e-12))
    return float(np.degrees(np.arctan2(d[0], np.hypot(d[1], d[2])))), float(np.degrees(np.arctan2(-d[1], d[2])))


def face_camera_offset(R: np.ndarray, t: np.ndarray, scale: float, pivot: np.ndarray, fraction: float,
                       limit_deg: float, perspective: bool = True, to_camera: np.ndarray | None = None) -> PoseOffset:
    """The yaw and pitch offset that turns a head (pose R, t, scale as in :func:`apply_pose_offset`)
    ``fraction`` (0-1) of the way from its own yaw and pitch to looking along ``to_camera`` (3,)
    (default :func:`camera_direction`: into the camera; :func:`facing_angles`), each clamped to
    ``limit_deg``. Roll is left as it is."""
    if to_camera is None:
        to_camera = camera_direction(R, t, scale, pivot, perspective)
    target_yaw, target_pitch = facing_angles(R, to_camera)
    yaw, pitch, _ = euler_from_rotation(R)
    f = float(np.clip(fraction, 0.0, 1.0))
    lim = abs(float(limit_deg))
    return PoseOffset(yaw=float(np.clip(f * (target_yaw - yaw), -lim, lim)),
                      pitch=float(np.clip(f * (target_pitch - pitch), -lim, lim)))


def smooth_values(previous: np.ndarray | None, target: np.ndarray, dt_s: float, time_constant_s: float) -> np.ndarray:
    """``previous`` (N,) moved toward ``target`` (N,) by an exponential filter with
    ``time_constant_s`` (s) over ``dt_s`` (s) of video; ``target`` itself when there is no previous
    or no smoothing. Returns a new (N,) float64 array."""
    target = np.asarray(target, np.float64)
    if previous is None or time_constant_s <= 0:
        return target.copy()
    k = 1.0 - float(np.exp(-max(dt_s, 0.0) / time_constant_s))
    previous = np.asarray(previous, np.float64)
    return previous + k * (target - previous)


def smooth_offset(previous: PoseOffset | None, target: PoseOffset, dt_s: float, time_constant_s: float) -> PoseOffset:
    """``previous`` moved toward ``target`` by an exponential filter with ``time_constant_s`` (s)
    over ``dt_s`` (s) of video; ``target`` itself when there is no previous or no smoothing."""
    if previous is None or time_constant_s <= 0:
        return target
    return PoseOffset(*smooth_values(previous.as_list(), target.as_list(), dt_s, time_constant_s))
