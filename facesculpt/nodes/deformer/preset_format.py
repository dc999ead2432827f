"""The deformer preset document (JSON): checks that need no mesh, the strength multiplier, and
reading a file or a shipped preset by name.

A preset is an object::

    {"format": "facesculpt-deformer-preset", "version": 1, "units": "mm",
     "strength": 1.0,                                   # optional, 0..3, multiplies every offset
     "landmarks": {"nose_tip": [x, y, z], ...},         # optional: the neutral it was made on, mm
     "topology": {...},                                 # optional: the mesh it was made on
     "pose": {"yaw": 10, "pitch": -5},                 # optional: the head's pose offset (issue 18)
     "static": [HANDLE, ...],                           # pinned points
     "edits": [{"handles": [HANDLE + {"offset": [dx, dy, dz]}, ...],   # mm, model space
                "roi": {"radius": 40.0, "metric": "geodesic"}}, ...]}

where a HANDLE names a landmark (``{"landmark": "nose_tip"}``), or a vertex with its rest
position (``{"vertex": 115, "point": [x, y, z]}``: exact on the same mesh topology, carried
through ``landmarks`` onto any other, :mod:`.landmark_warp`), or both. An edit or a pin may
carry its own ``topology`` and ``landmarks`` (:func:`merge_presets` of presets made on different
meshes), which then replace the document's for it. ``pose`` names any of yaw, pitch, roll
(degrees) and x, y, z (mm, camera axes) of :class:`facesculpt.geometry.pose_offset.PoseOffset`
(each within its limits); the deformer applies it on load (a preset without one leaves the pose
as it is) and saves a non-zero pose back.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

from facesculpt.geometry.pose_offset import MAX_OFFSET_MM, OFFSET_LIMITS, OFFSET_NAMES, PoseOffset

from .anchors import METRICS
from .errors import DeformerError

PRESET_FORMAT = "facesculpt-deformer-preset"
PRESET_VERSION = 1
#: The strength a preset's offsets may be multiplied by (inclusive).
STRENGTH_RANGE = (0.0, 3.0)
#: What says which mesh a preset (or one of its edits or pins) was made on.
ORIGIN_KEYS = ("topology", "landmarks")


def check_strength(value, what: str = "strength") -> float:
    """``value`` as a float in :data:`STRENGTH_RANGE`; DeformerError naming it otherwise."""
    lo, hi = STRENGTH_RANGE
    try:
        s = float(value)
    except (TypeError, ValueError):
        s = float("nan")
    if isinstance(value, bool) or not lo <= s <= hi:
        raise DeformerError(f"{what} {value!r} is outside {lo:g}..{hi:g} (a multiplier of the preset's offsets)")
    return s


def _finite3(value, what: str) -> None:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise DeformerError(f"preset {what} {value!r} is not 3 finite numbers")


def _check_handle(h, where: str) -> None:
    if not isinstance(h, dict):
        raise DeformerError(f"preset {where} must be an object, got {h!r}")
    if not any(k in h for k in ("landmark", "vertex", "point")):
        raise DeformerError(f"preset {where} {h!r} names neither a landmark nor a vertex")
    if "landmark" in h and not isinstance(h["landmark"], str):
        raise DeformerError(f"preset {where} landmark must be a name, got {h['landmark']!r}")
    if "vertex" in h and (isinstance(h["vertex"], bool) or not isinstance(h["vertex"], int)):
        raise DeformerError(f"preset vertex must be an integer, got {h['vertex']!r}")
    if "point" in h:
        _finite3(h["point"], "handle point")
    _check_origin(h)
    aliases = h.get("aliases", [])
    if not isinstance(aliases, list) or not all(isinstance(a, str) for a in aliases):
        raise DeformerError(f"preset {where} aliases must be a list of names, got {aliases!r}")


def _check_origin(item: dict) -> None:
    marks = item.get("landmarks", {})
    if not isinstance(marks, dict):
        raise DeformerError("malformed preset: 'landmarks' is not an object of name -> [x, y, z]")
    for name, p in marks.items():
        _finite3(p, f"landmark {name!r} position")
    if not isinstance(item.get("topology", {}), dict):
        raise DeformerError("malformed preset: 'topology' is not an object")


def _check_edit(item, k: int) -> None:
    if not isinstance(item, dict) or not isinstance(item.get("handles"), list):
        raise DeformerError(f"malformed preset: edit {k} is not an object with a list of 'handles'")
    _check_origin(item)
    if not item["handles"]:
        raise DeformerError(f"preset edit {k} has no handles")
    for h in item["handles"]:
        _check_handle(h, "handle")
        if "offset" not in h:
            raise DeformerError(f"malformed preset: a handle of edit {k} has no 'offset'")
        _finite3(h["offset"], "offset")
    roi = item.get("roi", {})
    if not isinstance(roi, dict):
        raise DeformerError(f"malformed preset: the roi of edit {k} is not an object")
    if "radius" in roi:
        r = roi["radius"]
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not np.isfinite(r) or r <= 0:
            raise DeformerError(f"ROI radius must be a positive number of mm, got {r!r}")
    if "metric" in roi and roi["metric"] not in METRICS:
        raise DeformerError(f"unknown ROI metric {roi['metric']!r} (use one of {METRICS})")


def preset_pose(preset: dict) -> PoseOffset | None:
    """The preset's ``pose`` as a PoseOffset; None when it has none. DeformerError in one sentence
    when it is not an object of yaw/pitch/roll (degrees) and x/y/z (mm) numbers within the limits."""
    pose = preset.get("pose")
    if pose is None:
        return None
    if not isinstance(pose, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                             for v in pose.values()):
        raise DeformerError(f"preset pose must be an object such as {{\"yaw\": 10, \"pitch\": -5}}, got {pose!r}")
    try:
        return PoseOffset(**{k: float(v) for k, v in pose.items()})
    except TypeError:
        raise DeformerError(f"preset pose names only yaw, pitch, roll, x, y, z, got {sorted(pose)}") from None
    except ValueError as exc:
        raise DeformerError(f"preset {exc}") from None


def pose_to_preset(offset: PoseOffset) -> dict:
    """The preset's ``pose`` object of ``offset``: its non-zero components by name."""
    return {k: v for k, v in zip(OFFSET_NAMES, offset.as_list()) if v}


def validate_preset(preset) -> None:
    """Check a preset document without a mesh (format, version, shapes, finite numbers, ROI,
    strength); DeformerError in one sentence at the first problem. Whether its landmarks exist
    is for the model to say (:meth:`EditStack.apply_preset`)."""
    if not isinstance(preset, dict) or preset.get("format") != PRESET_FORMAT:
        raise DeformerError(f"not a {PRESET_FORMAT} document")
    if preset.get("version") != PRESET_VERSION:
        raise DeformerError(f"preset version {preset.get('version')!r} is not {PRESET_VERSION}")
    if "strength" in preset:
        check_strength(preset["strength"], "preset strength")
    if not isinstance(preset.get("edits"), list):
        raise DeformerError("malformed preset: 'edits' is not a list")
    if not isinstance(preset.get("static", []), list):
        raise DeformerError("malformed preset: 'static' is not a list")
    preset_pose(preset)
    for h in preset.get("static", []):
        _check_handle(h, "pin")
    _check_origin(preset)
    for k, item in enumerate(preset["edits"]):
        _check_edit(item, k)


def scale_preset(preset: dict, strength: float = 1.0) -> dict:
    """A copy of ``preset`` whose offsets are multiplied by ``strength`` and by the preset's own
    ``"strength"`` field (each in 0..3, default 1), which the copy no longer has (its offsets
    now hold it). Its ``pose`` is multiplied too (each component clamped to its limit). ROI radii
    and pins are unchanged. DeformerError naming a strength outside 0..3 or a malformed preset."""
    s = check_strength(strength)
    validate_preset(preset)
    out = copy.deepcopy(preset)
    s *= check_strength(out.pop("strength", 1.0), "preset strength")
    for item in out["edits"]:
        for h in item["handles"]:
            h["offset"] = [float(x) * s for x in h["offset"]]
    if out.get("pose") is not None:
        limits = dict(zip(OFFSET_NAMES, OFFSET_LIMITS))
        out["pose"] = {k: float(np.clip(float(v) * s, -limits.get(k, MAX_OFFSET_MM), limits.get(k, MAX_OFFSET_MM)))
                       for k, v in out["pose"].items()}
    return out


def merge_presets(presets: list[dict], strength: float = 1.0) -> dict:
    """One preset holding the edits (in order) and pins of several, e.g. nose, then chin, then
    cheeks (the paper's Fig. 6e); later edits of the same handle win when applied. Each
    preset's offsets are multiplied by ``strength`` and by its own ``"strength"``
    (:func:`scale_preset`). Presets made on different meshes keep their own: each of their
    edits and pins carries its preset's ``topology`` and ``landmarks``. Their poses add up
    (clamped to the limits). DeformerError when there is none, or one is malformed or its
    strength is outside 0..3."""
    if not presets:
        raise DeformerError("no preset to merge")
    scaled = [scale_preset(p, strength) for p in presets]
    origins = [{k: p[k] for k in ORIGIN_KEYS if k in p} for p in scaled]
    shared = all(o == origins[0] for o in origins)
    out = {"format": PRESET_FORMAT, "version": PRESET_VERSION, "units": "mm", **(origins[0] if shared else {}),
           "static": [], "edits": []}
    for p, origin in zip(scaled, origins):
        own = {} if shared else origin
        out["static"] += [dict(r, **own) for r in p.get("static", [])]
        out["edits"] += [dict(e, **own) for e in p["edits"]]
    poses = [preset_pose(p) for p in scaled if p.get("pose") is not None]
    if poses:
        out["pose"] = pose_to_preset(sum(poses[1:], poses[0]))
    return out


def read_preset_file(path: str | Path) -> dict:
    """Read and check a preset file; DeformerError naming the file when it is missing,
    unreadable, not JSON or not a valid preset."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise DeformerError(f"cannot read preset {path}: {exc}") from None
    try:
        validate_preset(doc)
    except DeformerError as exc:
        raise DeformerError(f"preset {path}: {exc}") from None
    return doc


def find_preset(name_or_path: str, preset_dir: str | Path = "") -> Path:
    """The file of a preset given as a path (relative to ``preset_dir`` when given, else to the
    current directory) or as the name of a shipped one (``nose_longer``, ``chin``, ``cheeks``).
    DeformerError in one sentence when it is neither."""
    from facesculpt.paths import preset_file

    if not name_or_path:
        raise DeformerError("a preset needs a file path or the name of a shipped preset")
    p = Path(name_or_path).expanduser()
    if not p.is_absolute() and preset_dir:
        p = Path(preset_dir).expanduser() / p
    if p.is_file():
        return p
    try:
        return preset_file(name_or_path)
    except FileNotFoundError as exc:
        raise DeformerError(f"{exc}; no file {p.resolve()} either") from None
