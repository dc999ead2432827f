"""Edit layers on top of ARAP: several edits accumulate (nose stretched, then chin pointed,
then both cheeks — the paper's Fig. 6e), undo, reset, and JSON presets.

An *edit* is one gesture: one or more handle vertices with their model-space offsets (mm,
from the handle's rest position) and the ROI around them (a radius on the neutral mesh, or
explicit vertices). All edits are solved together: every edit's handles stay where that
edit put them (a later edit of the same vertex wins), the ROIs are united, and whatever no
ROI covers stays fixed. The result is the displacement ``M_m - M_bar`` (V, 3) in mm.

Presets (:mod:`.preset_format`) name handles by the model's landmark names where a handle is
a landmark vertex; any other handle is stored with its vertex index (exact on the same
topology) and its rest position, which the preset's copy of the neutral's named landmarks
carries onto another person or another model (:mod:`.landmark_warp`). They store offsets and
ROI radii (mm), so a preset made on one person applies to another person and to any model
that names the same landmarks (on another model, its offsets are turned into that model's axes
by the landmarks both name).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .anchors import METRICS, distances_from, edge_length_graph, roi_within_radius
from .arap import ArapDeformer
from .deformer_options import GRIP, GRIP_RANGE, SETTLE_TOLERANCE, DeformerOptions
from .errors import DeformerError
from .landmark_warp import face_size, frame_rotation, landmark_positions, nearest_vertices, warp_points
from .preset_format import ORIGIN_KEYS, PRESET_FORMAT, PRESET_VERSION, read_preset_file, scale_preset
from .solve_mesh import MIN_SOLVE_VERTICES, MIN_SOLVE_VERTICES_RANGE, solve_mesh

__all__ = [
    "GRIP", "GRIP_RANGE", "SETTLE_ITERATIONS", "SETTLE_TOLERANCE", "PRESET_FORMAT",
    "PRESET_VERSION", "Edit", "EditStack", "topology_signature",
]

DEFAULTS = DeformerOptions()
SETTLE_ITERATIONS = 2000  # the most iterations :meth:`EditStack.settle` takes to get there


@dataclass
class Edit:
    """One gesture. ``offsets`` maps handle vertex -> (3,) float64 mm from its rest position;
    ``roi_radius``/``roi_metric`` give the ROI around the handles unless ``roi`` lists it;
    ``base`` is the displacement the edit started from (its grips move relative to it)."""

    offsets: dict[int, np.ndarray] = field(default_factory=dict)
    roi_radius: float = DEFAULTS.roi_radius
    roi_metric: str = DEFAULTS.roi_metric
    roi: np.ndarray | None = None
    base: np.ndarray | None = None  # (Vf, 3) mm, the solve mesh's displacement when the edit began


def topology_signature(n_vertices: int, triangles: np.ndarray) -> dict:
    """Identifies a mesh topology: vertex and triangle counts and a CRC32 of the triangles."""
    T = np.ascontiguousarray(np.asarray(triangles, dtype=np.int32))
    return {"vertices": int(n_vertices), "triangles": int(T.shape[0]), "crc32": int(zlib.crc32(T.tobytes()))}


class EditStack:
    """The edits on one neutral mesh and the ARAP solve that realises them.

    vertices: (V, 3) neutral mesh, model space, mm; triangles: (T, 3).
    landmark_names / landmark_vertices: the model's named vertices (FaceModel) for presets and
    for pressing at a landmark. roi_radius (mm) and roi_metric ("geodesic" | "euclidean"): the
    default ROI of a new edit. ``grip`` (share of an edit's ROI radius, in ``GRIP_RANGE``): the
    skin around each handle that moves rigidly with it (0: the handle vertex alone).
    ``min_solve_vertices``: a mesh with fewer vertices is solved on its refinement
    (:mod:`.solve_mesh`; 0: always on the mesh itself). ``deformer_options`` go to
    :class:`ArapDeformer`, which works on the solve mesh (``self.solve_mesh``).
    Methods raise :class:`DeformerError` on bad input and leave the stack as it was.
    """

    def __init__(
        self,
        vertices: np.ndarray,
        triangles: np.ndarray,
        landmark_names=(),
        landmark_vertices=(),
        roi_radius: float = DEFAULTS.roi_radius,
        roi_metric: str = DEFAULTS.roi_metric,
        grip: float = GRIP,
        min_solve_vertices: int = MIN_SOLVE_VERTICES,
        **deformer_options,
    ):
        low, high = MIN_SOLVE_VERTICES_RANGE
        if isinstance(min_solve_vertices, bool) or not isinstance(min_solve_vertices, (int, np.integer)) \
                or not low <= min_solve_vertices <= high:
            raise DeformerError(f"min_solve_vertices must be an integer in [{low}, {high}], got {min_solve_vertices!r}")
        model = ArapDeformer(vertices, triangles, **deformer_options)   # checks the mesh and the options
        self.rest, self.triangles, self.n = model.rest, model.triangles, model.n
        self.solve_mesh = solve_mesh(self.rest, self.triangles, int(min_solve_vertices))
        self.deformer = model if self.solve_mesh.levels == 0 else \
            ArapDeformer(self.solve_mesh.rest, self.solve_mesh.triangles, **deformer_options)
        # Local/global steps shrink with the squared edge length on a refined mesh (its smooth
        # modes converge more slowly), so a step that small is further from the solution: the
        # tolerance shrinks as much, and a solve stops as close to it as on the model's mesh.
        self._tolerance_scale = 4.0 ** -self.solve_mesh.levels
        self.deformer.tolerance *= self._tolerance_scale
        self._rest = self.solve_mesh.rest   # the solve mesh's rest; its first n vertices are the model's
        names = list(landmark_names)
        idx = np.asarray(landmark_vertices, dtype=np.int64).ravel()
        if len(names) != idx.size:
            raise DeformerError(f"{len(names)} landmark names but {idx.size} landmark vertices")
        if idx.size and (idx.min() < 0 or idx.max() >= self.n):
            raise DeformerError("landmark vertices out of range")
        self.landmarks: dict[str, int] = {str(k): int(v) for k, v in zip(names, idx)}
        # every name of a vertex, descriptive names ("nose_tip") before numbers ("31"): a preset
        # stores them all and a model with any one of them can place the handle
        self._names_of: dict[int, list[str]] = {}
        for k, v in self.landmarks.items():
            self._names_of.setdefault(v, []).append(k)
        for names in self._names_of.values():
            names.sort(key=lambda k: k.isdigit())
        self._check_roi(roi_radius, roi_metric)
        self.roi_radius = float(roi_radius)
        self.roi_metric = roi_metric
        if not (np.isfinite(grip) and GRIP_RANGE[0] <= grip <= GRIP_RANGE[1]):
            raise DeformerError(f"grip must be a share of the ROI radius in {list(GRIP_RANGE)}, got {grip!r}")
        self.grip = float(grip)
        self._grips: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}  # (vertex, radius, metric) -> (vertices, mm)
        self._graph = edge_length_graph(self._rest, self.solve_mesh.triangles)
        self.edits: list[Edit] = []
        self.static: set[int] = set()
        self.displacement = np.zeros_like(self.rest)  # last good solve, (V, 3) mm
        self._solved = np.zeros_like(self._rest)      # ... on the solve mesh, (Vf, 3) mm
        self.version = 0

    # -- building edits ----------------------------------------------------------------

    @staticmethod
    def _check_roi(radius, metric):
        if metric not in METRICS:
            raise DeformerError(f"unknown ROI metric {metric!r} (use one of {METRICS})")
        if not np.isfinite(radius) or radius <= 0:
            raise DeformerError(f"ROI radius must be a positive number of mm, got {radius!r}")

    def _vertex(self, v) -> int:
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
            raise DeformerError(f"vertex index must be an integer, got {v!r}")
        if not 0 <= int(v) < self.n:
            raise DeformerError(f"vertex {v} out of range 0..{self.n - 1}")
        return int(v)

    def landmark_vertex(self, name: str) -> int:
        """Vertex of a landmark name; DeformerError naming a few known names when unknown."""
        if name not in self.landmarks:
            known = ", ".join(sorted(self.landmarks)[:12])
            raise DeformerError(f"no landmark named {name!r} in this model (known: {known}, ...)")
        return self.landmarks[name]

    def begin(self, vertices, roi_radius: float | None = None, roi_metric: str | None = None, roi=None) -> int:
        """Start a new edit with these handle vertices at their current positions (offset as
        the solved mesh has them, so pressing does not move anything). Returns its index."""
        vs = [self._vertex(v) for v in np.atleast_1d(np.asarray(vertices)).tolist()] if np.size(vertices) else []
        if not vs:
            raise DeformerError("an edit needs at least one handle vertex")
        if len(set(vs)) != len(vs):
            raise DeformerError("an edit lists a handle vertex twice")
        radius = self.roi_radius if roi_radius is None else float(roi_radius)
        metric = self.roi_metric if roi_metric is None else roi_metric
        self._check_roi(radius, metric)
        edit = Edit({v: self._solved[v].copy() for v in vs}, radius, metric, None, self._solved.copy())
        if roi is not None:
            edit.roi = np.unique(np.asarray([self._vertex(int(r)) for r in np.asarray(roi).ravel()], dtype=np.int64))
        self.edits.append(edit)
        return len(self.edits) - 1

    def add_handle(self, vertex: int, edit: int = -1) -> None:
        """Add a handle vertex to an edit (e.g. a second finger in a two-handle squeeze)."""
        v = self._vertex(vertex)
        e = self._edit(edit)
        if v not in e.offsets:
            e.offsets[v] = self._solved[v].copy()

    def _edit(self, edit: int) -> Edit:
        if not self.edits:
            raise DeformerError("there is no edit to change: press a handle first")
        try:
            return self.edits[edit]
        except (IndexError, TypeError):
            raise DeformerError(f"no edit {edit!r} (there are {len(self.edits)})") from None

    def _handle_vector(self, vertex: int, value, edit: int, what: str) -> tuple[Edit, int, np.ndarray]:
        """Validate a (3,) mm vector for one handle of an edit; returns (edit, vertex, vector)."""
        d = np.asarray(value, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)):
            raise DeformerError(f"a handle {what} must be 3 finite numbers, got {value!r}")
        e = self._edit(edit)
        v = self._vertex(vertex)
        if v not in e.offsets:
            raise DeformerError(f"vertex {v} is not a handle of that edit")
        return e, v, d

    def move_handle(self, vertex: int, delta, edit: int = -1) -> None:
        """Add a model-space displacement (3,) mm to one handle of an edit."""
        e, v, d = self._handle_vector(vertex, delta, edit, "displacement")
        e.offsets[v] = e.offsets[v] + d

    def set_offset(self, vertex: int, offset, edit: int = -1) -> None:
        """Place one handle of an edit at rest + ``offset`` (3,) mm."""
        e, v, d = self._handle_vector(vertex, offset, edit, "offset")
        e.offsets[v] = d

    def edit_of(self, vertex: int) -> int | None:
        """Index of the latest edit that holds ``vertex`` as a handle, or None."""
        for k in range(len(self.edits) - 1, -1, -1):
            if int(vertex) in self.edits[k].offsets:
                return k
        return None

    def handle_position(self, vertex: int) -> np.ndarray:
        """Current model-space target (3,) of a handle (latest edit that holds it), or its
        solved position when it is not a handle."""
        v = self._vertex(vertex)
        for e in reversed(self.edits):
            if v in e.offsets:
                return self.rest[v] + e.offsets[v]
        return self.rest[v] + self._solved[v]

    def toggle_static(self, vertex: int) -> bool:
        """Pin (or unpin) a vertex at its rest position. Returns True when now pinned."""
        v = self._vertex(vertex)
        if v in self.static:
            self.static.remove(v)
            return False
        self.static.add(v)
        return True

    def undo(self) -> bool:
        """Drop the last edit. False when there was none."""
        if not self.edits:
            return False
        self.edits.pop()
        return True

    def clear(self) -> None:
        """Drop every edit and pin (reset)."""
        self.edits.clear()
        self.static.clear()

    # -- solving -----------------------------------------------------------------------

    def anchors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(static, handles, roi, handle targets (H, 3) mm) for the current edits, as vertex indices of
        the solve mesh (the model's vertices first; a refined one adds ROI vertices past ``n``)."""
        targets: dict[int, np.ndarray] = {}
        for e in self.edits:
            targets.update(e.offsets)  # a later edit of the same vertex wins
        static = np.array(sorted(self.static - set(targets)), dtype=np.int64)
        handles = np.array(sorted(targets), dtype=np.int64)
        roi_mask = np.zeros(len(self._rest), bool)
        for e in self.edits:
            if e.roi is not None:
                roi_mask |= self.solve_mesh.inside(e.roi)
            else:
                seeds = np.array(sorted(e.offsets), dtype=np.int64)
                roi_mask[roi_within_radius(self._rest, seeds, e.roi_radius, e.roi_metric, graph=self._graph)] = True
        roi_mask[handles] = False
        roi_mask[static] = False
        offsets = np.array([targets[v] for v in handles]).reshape(-1, 3)
        return static, handles, np.flatnonzero(roi_mask), self._rest[handles] + offsets

    def _grip_radius(self, edit: Edit, vertex: int) -> float:
        """mm: ``grip`` of the edit's ROI radius, or of the explicit ROI's reach from ``vertex``."""
        if edit.roi is None or edit.roi.size == 0:
            return edit.roi_radius * self.grip
        return float(np.linalg.norm(self.rest[edit.roi] - self.rest[vertex], axis=1).max()) * self.grip

    def _grip_of(self, vertex: int, radius: float, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, distances mm) within ``radius`` of ``vertex``, the vertex itself excluded."""
        key = (vertex, radius, metric)
        if key not in self._grips:
            # no "at least the neighbours" rule: on the face mesh's coarse outline a neighbour can
            # lie half an ROI away, and moving it rigidly overshot the cheeks and jaw edits
            d = distances_from(self._rest, [vertex], metric, graph=self._graph, limit=radius)
            near = np.flatnonzero(d <= radius)
            near = near[near != vertex]
            self._grips[key] = (near, d[near])
        return self._grips[key]

    def constraints(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(static, constrained, roi, targets (C, 3) mm): :meth:`anchors` with every handle's
        grip (the ROI's free vertices within ``grip`` times its edit's ROI radius, or the explicit
        ROI's reach) moved rigidly
        with it (by the handle's offset since its edit began), each grip vertex with its nearest
        handle; pins and other handles keep theirs."""
        static, handles, roi, targets = self.anchors()
        if self.grip <= 0 or handles.size == 0:
            return static, handles, roi, targets
        offset = dict(zip(handles.tolist(), targets - self._rest[handles]))
        reach, base = {}, {}
        for e in self.edits:  # the latest edit that holds a handle sets its grip
            reach.update({v: (self._grip_radius(e, v), e.roi_metric) for v in e.offsets})
            base.update({v: e.base for v in e.offsets})
        free = set(roi.tolist())  # neither pinned nor a handle, and inside some edit's ROI
        best: dict[int, tuple[float, int]] = {}
        for h in handles.tolist():
            for v, d in zip(*self._grip_of(h, *reach[h])):
                if int(v) in free and (v not in best or d < best[v][0]):
                    best[int(v)] = (float(d), h)
        if not best:
            return static, handles, roi, targets
        # a grip moves as its handle moved since the edit began, so pressing moves nothing
        offset.update({v: offset[h] if base[h] is None else base[h][v] + offset[h] - base[h][h]
                       for v, (_, h) in best.items()})
        constrained = np.array(sorted(offset), dtype=np.int64)
        roi = np.setdiff1d(roi, constrained)
        return static, constrained, roi, self._rest[constrained] + np.array([offset[v] for v in constrained])

    def solve(self, iterations: int | None = None) -> np.ndarray:
        """Solve all edits; returns and keeps the displacement (V, 3) float64 mm.

        With no edit the displacement is zero. On DeformerError (e.g. an edit whose ROI holds
        no free vertex) the last good displacement stays and the error propagates.
        """
        if not self.edits:
            self.displacement = np.zeros_like(self.rest)
            self._solved = np.zeros_like(self._rest)
            self.deformer.reset()
            self.version += 1
            return self.displacement
        static, handles, roi, targets = self.constraints()
        self.deformer.set_anchors(static=static, handles=handles, roi=roi)
        self._solved = self.deformer.solve(targets, iterations=iterations) - self._rest
        self.displacement = self.solve_mesh.to_model(self._solved)
        self.version += 1
        return self.displacement

    @property
    def solved(self) -> np.ndarray:
        """(Vf, 3) float64 mm: the last solve on the solve mesh (:mod:`.solve_mesh`; its first
        ``n`` rows are the model's vertices, where every handle sits exactly at its offset), of
        which :attr:`displacement` is the model's share."""
        return self._solved

    def continue_from(self, other: EditStack) -> None:
        """Start the next solve from where ``other`` (a stack on the same mesh, e.g. the previous
        neutral of the same face) left its edits, instead of from the rest mesh."""
        if other._solved.shape == self._solved.shape:
            self.deformer.current = self._rest + other._solved

    def settle(self, iterations: int = SETTLE_ITERATIONS, tolerance: float = SETTLE_TOLERANCE) -> np.ndarray:
        """:meth:`solve` until the edits have settled on their ARAP solution (no vertex moving more
        than ``tolerance`` times the mesh's diagonal in an iteration, a quarter of that per level of
        the solve mesh's refinement; at most ``iterations``), as the live deformer's idle rounds do:
        a preset solved once for a video must not stop short of where the same preset settles in the
        window."""
        kept = self.deformer.tolerance
        self.deformer.tolerance = float(tolerance) * self._tolerance_scale
        try:
            return self.solve(iterations)
        finally:
            self.deformer.tolerance = kept

    # -- presets -----------------------------------------------------------------------

    def _ref(self, v: int) -> dict:
        """A handle or pin as a preset names it: by landmark name where the vertex has a
        descriptive one, else by its rest position (carried to other meshes through the
        landmarks); always with the vertex index (exact on the same topology)."""
        names = [k for k in self._names_of.get(v, []) if not k.isdigit()]
        if names:
            out = {"landmark": names[0], "vertex": v}
            if len(names) > 1:
                out["aliases"] = names[1:]
            return out
        return {"vertex": v, "point": [round(float(x), 4) for x in self.rest[v]]}

    def to_preset(self) -> dict:
        """JSON-ready dict of the edits and pins (:mod:`.preset_format`): handles named by
        landmark where possible, else placed relative to the neutral's named landmarks, which
        the preset carries."""
        edits = []
        for e in self.edits:
            item = {
                "handles": [dict(self._ref(v), offset=[float(x) for x in off]) for v, off in e.offsets.items()],
                "roi": {"radius": e.roi_radius, "metric": e.roi_metric},
            }
            if e.roi is not None:
                item["roi"]["vertices"] = [int(r) for r in e.roi]
            edits.append(item)
        marks = landmark_positions(self.rest, self.landmarks)
        return {
            "format": PRESET_FORMAT,
            "version": PRESET_VERSION,
            "units": "mm",
            "topology": topology_signature(self.n, self.triangles),
            "landmarks": {k: [round(float(x), 4) for x in p] for k, p in sorted(marks.items())},
            "static": [self._ref(v) for v in sorted(self.static)],
            "edits": edits,
        }

    def save_preset(self, path: str | Path) -> Path:
        """Write :meth:`to_preset` as JSON; returns the absolute path written (OSError when it
        cannot be written)."""
        path = Path(path).expanduser().resolve()
        path.write_text(json.dumps(self.to_preset(), indent=1))
        return path

    def _placement(self, origin: dict):
        """(same topology?, handle/pin dict -> vertex of this mesh, unit factor, axes (3, 3)) for
        presets made on the mesh ``origin`` describes (its optional ``topology`` and ``landmarks``).

        The unit factor takes the preset's mm to this mesh's: the ratio of the face sizes when
        the preset was made on another topology (another model, maybe in other units) and
        carries its landmarks; else 1. The axes turn its offsets into this mesh's model space
        (:func:`.landmark_warp.frame_rotation`), under the same condition; else the identity."""
        same = origin.get("topology") == topology_signature(self.n, self.triangles)
        marks = {k: np.asarray(p, np.float64) for k, p in origin.get("landmarks", {}).items()}
        mine = landmark_positions(self.rest, self.landmarks)
        theirs, ours = face_size(marks), face_size(mine)
        unit = 1.0 if same or theirs is None or ours is None else ours / theirs
        axes = np.eye(3) if same or not marks else frame_rotation(marks, mine)
        # numeric names are model-specific (mesh indices, iBUG numbers): from a preset made on
        # another mesh they would name other points here
        other_mesh = "topology" in origin and not same

        def resolve(ref: dict) -> int:
            name = ref.get("landmark")
            if name is not None and not (other_mesh and name.isdigit()):
                for alias in [name, *ref.get("aliases", [])]:
                    if alias in self.landmarks and not (other_mesh and alias.isdigit()):
                        return self.landmarks[alias]
                return self.landmark_vertex(name)  # raises, naming the landmark
            if same and "vertex" in ref:
                return self._vertex(ref["vertex"])
            if "point" in ref and marks:
                point = warp_points(np.asarray(ref["point"], np.float64), marks, mine)
                return int(nearest_vertices(self.rest, point)[0])
            if "point" in ref:
                raise DeformerError("a preset handle placed by its position needs the preset's 'landmarks'")
            raise DeformerError(
                f"preset handle at vertex {ref.get('vertex')} is not a named landmark and the preset was made on a "
                "different mesh topology"
            )

        return same, resolve, unit, axes

    def apply_preset(self, preset: dict, strength: float = 1.0) -> None:
        """Replace the edits and pins by those of a preset dict (:mod:`.preset_format`), its
        offsets multiplied by ``strength`` and its own ``"strength"`` (each 0..3). Nothing
        changes when the preset is malformed or names a landmark this model lacks
        (DeformerError). On another topology, offsets and ROI radii scale with the face size and
        offsets turn into this model's axes, where the preset carries its landmarks.
        An edit or pin with its own ``topology``/``landmarks`` (:func:`merge_presets` of presets
        made on different meshes) is placed by those."""
        preset = scale_preset(preset, strength)  # validates
        placements: dict[str, tuple] = {}

        def placement(item: dict) -> tuple:
            source = item if any(k in item for k in ORIGIN_KEYS) else preset
            origin = {k: source[k] for k in ORIGIN_KEYS if k in source}
            key = json.dumps(origin, sort_keys=True)
            if key not in placements:
                placements[key] = self._placement(origin)
            return placements[key]

        static = {placement(r)[1](r) for r in preset.get("static", [])}
        edits = []
        for item in preset["edits"]:
            same, resolve, unit, axes = placement(item)
            offsets = {resolve(h): unit * axes @ np.asarray(h["offset"], dtype=np.float64) for h in item["handles"]}
            roi = item.get("roi", {})
            radius = unit * float(roi["radius"]) if "radius" in roi else self.roi_radius
            metric = roi.get("metric", self.roi_metric)
            self._check_roi(radius, metric)
            explicit = None
            if "vertices" in roi and same:  # explicit ROI vertices only mean something on the same topology
                try:
                    explicit = np.unique(np.array([self._vertex(int(r)) for r in roi["vertices"]], dtype=np.int64))
                except (TypeError, ValueError) as exc:
                    if isinstance(exc, DeformerError):
                        raise
                    raise DeformerError(f"malformed preset: ROI vertices {exc}") from None
            edits.append(Edit(offsets, radius, metric, explicit))
        self.edits = edits
        self.static = static

    def load_preset(self, path: str | Path, strength: float = 1.0) -> None:
        """Read a preset file and apply it with ``strength`` (DeformerError when unreadable or
        malformed)."""
        self.apply_preset(read_preset_file(path), strength)
