"""The compositor: one frame in, the frame with the deformed face out (docs/architecture.md "Stages", 4).

Per frame, on a box around the part of the face that moves only:

1. the camera the fitter used is recovered from its (camera-space, pixel) vertex
   pairs (:mod:`.camera`), and the deformed vertices are projected with it; a face whose
   vertices all stay put (offset under ``IDENTITY_PX``) is returned as it came;
2. the mesh (holes closed, :mod:`.mesh`) is refined by Loop subdivision (:mod:`.subdivision`,
   one sparse matrix per triangle set), which carries the pixels, depths and offsets of the
   vertices to the fine mesh, so edited outlines and surfaces are smooth curves, not polygons;
3. OpenGL (moderngl) rasterises the fine deformed mesh, z-buffered, with each vertex's offset
   back to its undeformed pixel as attribute: per pixel, where its colour comes from in the
   input (:mod:`.source_map`); and the undeformed mesh: the original face region. Both are
   read back for the box only;
4. masks: the covered pixels whose offset is not negligible are the changed region (only those
   are re-rendered); the background the face no longer covers (original minus deformed region,
   slightly dilated) is filled: by default dragged in (:mod:`.drag_fill`: the background beside
   the face, carried by its motion), else inpainted from the surrounding background
   (:mod:`.inpaint`), each connected part on its own small box; with ``plate`` on, the
   background plate (:mod:`.background_plate`: the background seen in earlier frames outside the
   face grown by ``PLATE_MARGIN`` and outside every person the ``segmenter`` finds, registered
   when the camera moves) replaces the fill where it is known, fading into it at its border;
5. the input frame is sampled once at the source positions of the changed pixels (full
   resolution; by default a long windowed sinc, :mod:`.sinc_sampling`; :mod:`.warp`) and
   blended over the background with a soft edge inside the deformed outline, as wide as
   ``feather_px`` or ``FEATHER_FRACTION`` of the face's size if that is more; where the source
   map jumps (a fold of the moved surface) the changed pixels are anti-aliased. Only changed and
   inpainted pixels are written: every other pixel is the input's, bit for bit, by construction.
6. with ``atlas`` on (issue 16), the face's texture memory (:mod:`.texture_atlas`) is updated
   from the input frame (every ``atlas_every`` frames; :mod:`.atlas_raster`), and where the input
   sees a changed pixel's surface badly (stretched more than ``ATLAS_STRETCH`` to one, hidden or
   grazing: ``ATLAS_GRAZING``; :func:`.texture_atlas.blend_atlas`), its sampled colour is blended
   toward the atlas's, in the frame's lighting, as far as the atlas knows that texel.

Steps 4-5 run on the CPU: on llvmpipe a GPU pass would add an upload and a readback of the same
crop for work that numpy/OpenCV do cheaply on it (benchmarks/bench_renderer.py measures it).
"""

from __future__ import annotations

import dataclasses
import time

import cv2
import moderngl
import numpy as np

from facesculpt.geometry import point_bounds
from facesculpt.options import check_options

from . import motion_extension as extension
from .atlas_memory import AtlasMemory
from .atlas_raster import AtlasRasterizer
from .background_plate import BackgroundPlate
from .body_motion import body_box, carry_to_body, neck_motion, union_box
from .camera import estimate_projection, project
from .compositor_options import OUTLINE_BAND, CompositorOptions  # noqa: F401 (OUTLINE_BAND: its old home)
from .drag_fill import drag_fill, dragged_positions, smooth_drag
from .gl_context import create_headless_context
from .inpaint import dilate, fill_by_parts, uncovered_mask
from .keyframe_views import KeyframeViews, blend_keyframe, keyframe_weights
from .motion_extension import carry_past_outline, extend_motion, head_box, head_region
from .plate_learning import PlateLearner
from .render_meshes import RenderMesh, RenderMeshes
from .silhouette_source import mend, unseen_by_silhouette
from .sinc_sampling import Upsampled, upsampled_over
from .source_map import UNCOVERED, SourceMapRenderer
from .texture_atlas import TextureAtlas, blend_atlas
from .warp import (
    IDENTITY_PX,
    bounding_slices,
    changed_pixels,
    covered_pixels,
    feather_alpha,
    fold_edges,
    sharpen_silhouette,
    soften,
    source_positions,
    warp_frame,
)

FEATHER_FRACTION = 0.015  # the soft edge's least width as a share of the face's size
# Where the face's outline meets what it uncovered, its soft edge is only this wide (px): the anti-aliasing
# of a filmed silhouette. The wider feather blended the outline over the fill: a pale band along a narrowed jaw.
SILHOUETTE_FEATHER_PX = 2.0
FILL_CONTEXT_PX = 10      # the work box's background past the region the fill may fill (px)
PLATE_MARGIN = 0.04       # the background plate learns nothing this close to the face (share of its size)
STAGES = ("plate", "camera", "atlas", "draw", "readback", "masks", "inpaint", "texture", "composite", "total")


def face_size(projected: np.ndarray) -> float:
    """A face's size (px): the geometric mean of the sides of its pixels' (V, 2) bounding box."""
    lo, hi = point_bounds(projected)
    side = hi - lo
    return float(np.sqrt(max(side[0] * side[1], 0.0)))


class Compositor:
    """Renders a deformed face into video frames of one size. Usable without the graph.

    Compositor(width, height, options=CompositorOptions(), ctx=None, segmenter=None, **fields): frame
    size in pixels; ``options`` a :class:`.compositor_options.CompositorOptions` (every option's
    default, unit and range), whose fields may also be given by name; ``ctx`` a
    moderngl context to draw with (default: a headless EGL context of its own); ``inpaint`` the fill
    of what the face uncovers: "pushpull", "telea", "ns", "patch" (:mod:`.inpaint`) or "drag"
    (:mod:`.drag_fill`); ``feather_px`` least width of the soft edge inside the deformed outline
    (pixels; it grows to ``FEATHER_FRACTION`` of the face's size; 0: a hard edge); ``dilate_px``
    growth of the region to inpaint (pixels); ``interpolation`` the kernel the frame is sampled with
    ("sinc": a long windowed sinc, :mod:`.sinc_sampling`; "cubic", "lanczos", "linear": OpenCV's);
    ``subdivision`` Loop levels of the render mesh (None: per frame as few as make its edges
    ``max_fine_edge_px`` long on screen, at least one, within 16384 triangles and 2 levels; with
    ``max_fine_edge_px`` None, as many as that budget allows: :class:`.RenderMeshes`); ``atlas`` keep and use the
    face's texture memory (render's ``uv`` needed), ``atlas_size`` its texels a side, ``atlas_every``
    update it every N frames (the frames between only read it); ``atlas_blend`` False: learn the atlas,
    blend nothing from it (e.g. only to save it); ``atlas_thread``: its updates on a thread of its own,
    with a GL context of its own where one can be made (an update is skipped while the last one runs:
    not deterministic, for live use; :mod:`.atlas_memory`);
    ``plate`` keep a background plate (:class:`.background_plate.BackgroundPlate`; ``plate_max_age``
    frames an estimate is used, ``plate_register`` follow camera motion) and take uncovered pixels from
    it; ``segmenter`` a callable frame -> (H, W) uint8 0/1 mask of people, kept off the plate
    (:class:`.person_segmentation.PersonSegmenter`; None: only the face is); ``keyframes`` keep views of
    the face at other poses and take turned surface from them (:mod:`.keyframe_views`);
    ``outline_band`` how far past the fitted outline (share of the face's size, 0: not at all) a shape edit's
    motion is carried (:meth:`_read_map`). ``atlases``: a :class:`.texture_atlas.TextureAtlas` a face key, ``atlas`` the last.

    After each :meth:`render`: ``timings``, the stage times of that frame in ms (:data:`STAGES`;
    plate: the main thread's part of its learning); ``box``, the frame rectangle (x0, y0, x1, y1)
    it worked on (None when nothing changed); ``deformed_px``, the deformed vertices' (V, 2) pixels;
    ``meshes.last_levels``, the Loop levels of the mesh it drew.
    """

    def __init__(self, width: int, height: int, options: CompositorOptions | None = None, *,
                 ctx: moderngl.Context | None = None, segmenter=None, **overrides):
        width, height = int(width), int(height)
        if width <= 0 or height <= 0:
            raise ValueError(f"frame size must be positive, got {width}x{height}")
        try:  # a field given by name (Compositor(w, h, feather_px=2)) overrides ``options``
            o = dataclasses.replace(options or CompositorOptions(), **overrides)
        except TypeError as exc:
            raise TypeError(f"Compositor: {exc} (its options: CompositorOptions' fields)") from None
        check_options(o)
        self.options = o
        self.width, self.height = width, height
        self.inpaint = o.inpaint
        self.feather_px, self.outline_band, self.mend_silhouette = map(float, (o.feather_px, o.outline_band, o.mend_silhouette))
        self.dilate_px = int(o.dilate_px)
        self.telea_radius = float(o.telea_radius)
        self.interpolation = o.interpolation
        self.meshes = RenderMeshes(o.subdivision, o.max_fine_edge_px)
        self._own_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_headless_context()
        self.maps = SourceMapRenderer(self.ctx, width, height, extras=bool(o.atlas) or bool(o.keyframes))
        self.atlas_blend = bool(o.atlas_blend)
        self.memory = AtlasMemory(self.ctx, o.atlas_size, width, height, o.atlas_every, o.atlas_thread) if o.atlas else None
        # keyframes need how well this frame sees each vertex: the atlas's, when it sees every frame
        # on this thread, or a rasteriser of their own
        own = o.keyframes and not (self.memory is not None and self.memory.current)
        self._quality_raster = AtlasRasterizer(self.ctx, 16, width, height) if own else None
        self.views: dict | None = {} if o.keyframes else None   # face key -> KeyframeViews
        self.keyframe_used: int | None = None   # the frame index of the keyframe the last render blended in
        self.atlas_region: np.ndarray | None = None   # (h, w) float32 atlas weight of the last box
        self.plate = BackgroundPlate(width, height, max_age=o.plate_max_age, register=o.plate_register) if o.plate else None
        self.plate_region: np.ndarray | None = None   # (h, w) float32 plate weight of the last box
        self._plate_learner = PlateLearner(self.plate, segmenter) if o.plate else None
        self._mesh: RenderMesh | None = None   # the render mesh of the last frame
        self.timings: dict[str, float] = {}
        self.box: tuple[int, int, int, int] | None = None
        self.original_region = self.deformed_region = self.changed_region = self.inpainted_region = None  # last box's
        self.deformed_px: np.ndarray | None = None   # (V, 2) pixels of the last deformed mesh

    def drawn_px(self, px: np.ndarray) -> np.ndarray:
        """(V, 2) float: where the drawn (subdivided) surface of the last frame's mesh puts its
        vertices whose pixels are ``px`` (V, 2), e.g. :attr:`deformed_px`: a deformer may hand over
        a displacement whose subdivided surface, not the vertices themselves, follows the edit
        (``facesculpt/nodes/deformer/solve_mesh.py``), so marks on the face go here."""
        p = np.asarray(px, np.float64)
        if self._mesh is None or self._mesh.S.shape[1] != len(p):
            return p
        return np.asarray(self._mesh.S[: len(p)] @ p)

    def _set_triangles(self, triangles: np.ndarray, n_vertices: int, px: np.ndarray) -> None:
        """Make the render mesh of ``triangles`` current (:class:`.RenderMeshes`; the face's vertex
        pixels ``px`` (V, 2) choose its levels); ValueError for triangles that are not indices."""
        mesh = self.meshes.get(triangles, n_vertices, px)
        if self._mesh is None or mesh.key != self._mesh.key:
            self.maps.set_mesh(mesh.S.shape[0], mesh.fine.size // 3 + len(mesh.closed))
        self._mesh = mesh

    def _draw_triangles(self, offset: np.ndarray) -> tuple[np.ndarray, int]:
        """The triangles to draw, given the fine vertices' ``offset`` (Vf, 2) pixels: the fine
        children of every coarse triangle with a child vertex that moves (|offset| at least
        half of IDENTITY_PX), then the other coarse triangles as they are, on the fine mesh's
        first V vertices (their pixels do not move; drawn for occlusion only). Returns
        ((N, 3) int, how many of them are the moving fine ones)."""
        moving = np.einsum("ij,ij->i", offset, offset) >= (0.5 * IDENTITY_PX) ** 2
        corners = moving[self._mesh.fine]
        active = np.logical_or.reduce(corners[..., 0] | corners[..., 1] | corners[..., 2], axis=0)
        children = self._mesh.fine[:, active].reshape(-1, 3)
        return np.concatenate([children, self._mesh.closed[~active]]), len(children)

    def _check(self, frame, fitted, projected, deformed, keep_mask=None):
        if not (isinstance(frame, np.ndarray) and frame.dtype == np.uint8
                and frame.shape == (self.height, self.width, 3)):
            got = f"{frame.shape} {frame.dtype}" if isinstance(frame, np.ndarray) else type(frame).__name__
            raise ValueError(f"frame must be ({self.height}, {self.width}, 3) uint8 BGR, got {got}")
        if keep_mask is not None and np.shape(keep_mask) != (self.height, self.width):
            raise ValueError(f"keep_mask must be ({self.height}, {self.width}), got {np.shape(keep_mask)}")
        fitted = np.asarray(fitted, np.float64)
        projected = np.asarray(projected, np.float64)
        deformed = np.asarray(deformed, np.float64)
        V = fitted.shape[0] if fitted.ndim == 2 else -1
        if fitted.shape != (V, 3) or deformed.shape != (V, 3) or projected.shape != (V, 2):
            raise ValueError(f"need fitted (V, 3), projected (V, 2), deformed (V, 3) with one V; got "
                             f"{fitted.shape}, {projected.shape}, {deformed.shape}")
        for name, arr in (("fitted_vertices", fitted), ("projected_px", projected), ("deformed_vertices", deformed)):
            if not np.isfinite(arr).all():
                raise ValueError(f"{name} contains NaN or infinite values")
        return fitted, projected, deformed

    def deformed_pixels(self, fitted_vertices, projected_px, deformed_vertices, P: np.ndarray | None = None):
        """Pixels (V, 2) float64 and depth (V,) float64 of the deformed vertices.

        The camera ``P`` (3, 4) is recovered from the (fitted_vertices, projected_px) pairs when
        not given; the pixels are projected_px moved by the projected displacement, so zero
        deformation gives projected_px exactly.
        """
        if P is None:
            P = estimate_projection(fitted_vertices, projected_px)
        V = len(fitted_vertices)
        px, depth = project(P, np.concatenate([fitted_vertices, deformed_vertices]))  # one pass
        return projected_px + (px[V:] - px[:V]), depth[V:]

    # -- the frame ---------------------------------------------------------------------------
    def render(self, frame_bgr: np.ndarray, fitted_vertices: np.ndarray, projected_px: np.ndarray,
               triangles: np.ndarray, deformed_vertices: np.ndarray,
               keep_mask: np.ndarray | None = None, uv: np.ndarray | None = None, face_key=0,
               head_motion: bool = False) -> np.ndarray:
        """The frame with the face replaced by its deformed version.

        frame_bgr: (H, W, 3) uint8, the frame the face was fitted on (not modified).
        fitted_vertices: (V, 3) float, the fitted (undeformed) mesh in camera space (any units).
        projected_px: (V, 2) float, its projection into the frame, pixels (OpenCV convention:
            pixel centres at integer coordinates); where each vertex's colour is.
        triangles: (T, 3) int vertex indices of the mesh (holes are closed internally).
        deformed_vertices: (V, 3) float, the deformed mesh in the same camera space
            (Eq. 5: fitted + the edit rotated and scaled into the head pose).
        keep_mask: optional (H, W) bool, pixels composited back from the input afterwards (what
            is in front of the face, e.g. a hand: nothing re-rendered covers it); None: none.
        uv, face_key: the face's (V, 2) texture coordinates in [0, 1] and key, for its atlas (step 6).
        head_motion: carry the face's motion over the head around it (pose edits; :mod:`.motion_extension`);
            "body": and the chin's motion over the neck and body below the jaw (:mod:`.body_motion`).
        V = 0 (no face) returns a copy of the frame. Returns a new (H, W, 3) uint8 frame; it
        equals ``frame_bgr`` exactly wherever the source position is unchanged (offset under
        ``IDENTITY_PX``) and outside the union of the original and deformed face regions
        (grown by ``dilate_px``). Raises ValueError on inputs of the wrong shape, type or size.
        """
        try:
            return self._render(frame_bgr, fitted_vertices, projected_px, triangles, deformed_vertices, keep_mask, uv,
                                face_key, head_motion)
        finally:
            if self.memory is not None:   # the frame is drawn: the atlas's update may start
                self.memory.start()

    def _render(self, frame_bgr, fitted_vertices, projected_px, triangles, deformed_vertices, keep_mask, uv, face_key,
                head_motion) -> np.ndarray:
        """:meth:`render`'s work."""
        t_start = time.perf_counter()
        fitted, projected, deformed = self._check(frame_bgr, fitted_vertices, projected_px, deformed_vertices, keep_mask)
        self.box = self.original_region = self.deformed_region = self.changed_region = self.inpainted_region = None
        self.deformed_px = self.atlas_region = None
        V = fitted.shape[0]
        t_plate = self._learn_plate(frame_bgr, projected, keep_mask)
        if V == 0:  # no face
            self.timings = {"plate": t_plate, "total": (time.perf_counter() - t_start) * 1e3}
            return frame_bgr.copy()
        self._set_triangles(triangles, V, projected)
        t0 = time.perf_counter()
        P = estimate_projection(fitted, projected)   # the camera, once for the atlas, keyframes and warp
        t_P, t0 = time.perf_counter() - t0, time.perf_counter()
        uvq, chosen = self._update_memory(frame_bgr, fitted, projected, triangles, deformed, uv, face_key, keep_mask, P)
        t_atlas, t0 = (time.perf_counter() - t0) * 1e3, time.perf_counter() - t_P   # the camera's stage holds P
        dst_px, depth = self.deformed_pixels(fitted, projected, deformed, P)
        self.deformed_px = dst_px
        self._neck = neck_motion(fitted, projected, deformed, P) if head_motion == "body" else None
        offset = projected - dst_px
        moved = np.einsum("ij,ij->i", offset, offset) >= IDENTITY_PX ** 2
        box = self._work_box(projected, dst_px, moved, head_motion) if moved.any() else None
        out = frame_bgr.copy()
        if box is None:  # nothing moves, or not inside the frame: every later stage takes no time
            self.timings = {**dict.fromkeys(STAGES, 0.0), "camera": (time.perf_counter() - t0) * 1e3,
                            "atlas": t_atlas, "plate": t_plate, "total": (time.perf_counter() - t_start) * 1e3}
            return out
        fine = self._mesh.S @ np.column_stack([dst_px, depth, offset] + ([uvq] if uvq is not None else [])).astype(np.float32)
        draw_tris, n_moving = self._draw_triangles(fine[:, 3:5])
        t1 = time.perf_counter()
        self.maps.draw(fine[:, 0:2], fine[:, 2], fine[:, 3:5], draw_tris, n_moving, box, self._extras(fine))
        t2 = time.perf_counter()
        offsets, orig_mask, face, dragged, behind = self._read_map(box, projected, dst_px, head_motion)
        t3 = time.perf_counter()
        covered, changed, fill, source = self._masks(offsets, orig_mask, projected)
        t4 = time.perf_counter()
        x0, y0, x1, y1 = box
        crop = out[y0:y1, x0:x1]
        write = changed | (covered & (fill != 0))
        block = bounding_slices(write)
        positions = None if block is None else source_positions(offsets[block], (x0 + block[1].start, y0 + block[0].start))
        shared = source is not None and dragged is not None and block is not None   # two samplings: one upsampling
        upsampled = (upsampled_over(frame_bgr, [positions, dragged_positions(fill, dragged, box[:2])])
                     if shared and self.interpolation == "sinc" else None)
        t_up = time.perf_counter() - t4   # the sampling's (the texture stage's), though the fill uses it first
        if source is not None:  # in place: the crop becomes the background (the face is blended over it below)
            self._fill(crop, fill, source, box, projected, (frame_bgr, dragged, orig_mask | face.view(np.uint8)),
                       upsampled)
        t5 = time.perf_counter()
        warped = None
        if block is not None:
            at = (x0 + block[1].start, y0 + block[0].start)   # the block's top-left frame pixel
            warped = warp_frame(frame_bgr, offsets[block], at, self.interpolation, upsampled, positions)
            self._blend_memory(warped, block, offsets, changed, box, uvq is not None, (fine, draw_tris, n_moving, chosen))
            if head_motion is True and self.mend_silhouette:  # what the input saw only at its outline, from beside it
                mend(warped, unseen_by_silhouette(offsets, face, orig_mask)[block], face[block])
            if behind is not None:  # a pose edit's outline over what lies behind it, with an edit's soft edge
                alpha = feather_alpha(face.view(np.uint8), self.feather_width(projected))[block]
                extension.over_behind(warped, frame_bgr, behind[block], alpha, at, "cubic")
        t6 = time.perf_counter()
        if block is not None:
            self._composite(crop, warped, block, offsets, covered, changed, write, self.feather_width(projected), fill)
        if keep_mask is not None:  # what is in front of the face is the input's, bit for bit
            np.copyto(crop, frame_bgr[y0:y1, x0:x1], where=np.asarray(keep_mask[y0:y1, x0:x1], bool)[..., None])
        t7 = time.perf_counter()
        self.box = box
        self.original_region, self.deformed_region = orig_mask, face.view(np.uint8)
        self.changed_region, self.inpainted_region = changed.view(np.uint8), fill
        self.timings = {
            "camera": (t1 - t0) * 1e3, "atlas": t_atlas, "draw": (t2 - t1) * 1e3, "readback": (t3 - t2) * 1e3,
            "plate": t_plate, "masks": (t4 - t3) * 1e3, "inpaint": (t5 - t4 - t_up) * 1e3,
            "texture": (t6 - t5 + t_up) * 1e3,
            "composite": (t7 - t6) * 1e3, "total": (time.perf_counter() - t_start) * 1e3}
        return out

    def _read_map(self, box: tuple[int, int, int, int], projected: np.ndarray, dst_px: np.ndarray,
                  head_motion: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The source map's offsets and original region of ``box`` (:meth:`.SourceMapRenderer.read`), the (h, w) bool
        deformed face, the drag fill's offsets into what the face uncovered and a pose edit's behind its folded outline
        (each None otherwise); with ``head_motion``, the offsets carried over the head region around the face at
        ``projected`` and ``dst_px`` (V, 2) px (:mod:`.motion_extension`), else over the outline band (:meth:`band_px`)."""
        offsets, orig_mask = self.maps.read(box)
        face = covered_pixels(offsets)
        dragged = behind = None
        if head_motion:
            both = np.concatenate([projected, dst_px])
            if head_motion == "body":  # the head's extension on the head's own box, the body's motion below it
                x0, y0, x1, y1 = head_box(both, self.width, self.height) or box
                part = (slice(y0 - box[1], y1 - box[1]), slice(x0 - box[0], x1 - box[0]))
                offsets = offsets.copy()
                offsets[part] = extend_motion(offsets[part], head_region(offsets[part].shape[:2], (x0, y0), both))
                offsets = carry_to_body(offsets, face, box[:2], dst_px, self._neck)
            else:
                region = head_region(offsets.shape[:2], box[:2], both)
                goes_on = extension.head_goes_on(face.shape, box[:2], dst_px)
                offsets, behind = extension.extend_behind_outline(offsets, region, self.feather_width(projected), goes_on)
        elif self.outline_band > 0 or self.inpaint == "drag":  # past both outlines; what the face uncovered is filled
            gap = (orig_mask != 0) & ~face if self.inpaint == "drag" else None
            offsets = carry_past_outline(offsets, face.view(np.uint8) | orig_mask, self.band_px(projected), gap)
            if gap is not None:
                dragged = smooth_drag(offsets, gap)   # a new array, unless it changed nothing
                if dragged is offsets:
                    offsets = offsets.copy()
                offsets[gap] = UNCOVERED
        return offsets, orig_mask, face, dragged, behind

    def _fill(self, crop: np.ndarray, fill: np.ndarray, source: np.ndarray, box: tuple[int, int, int, int],
              projected: np.ndarray, drag: tuple, upsampled: Upsampled | None = None) -> None:
        """Fill the ``fill`` pixels of ``crop`` (the frame's ``box``, in place) from the ``source``
        pixels (step 4), then lay the background plate over them where it knows the background.
        ``drag``: (the input frame, the dragged offsets or None, the face before and after) for the
        drag fill (:func:`.drag_fill.drag_fill`, through ``upsampled``; push-pull where it does not reach)."""
        frame, dragged, face = drag
        rest, known, method = fill, source, self.inpaint
        if dragged is not None:
            done = drag_fill(crop, frame, fill, dragged, face, box[:2], self.interpolation, upsampled)
            rest, known, method = fill & ~done.view(np.uint8), source | done, "pushpull"
        fill_by_parts(crop, rest, known, method, radius=self.telea_radius, in_place=True)
        if self.plate is not None:
            self.plate_sync()
            if dragged is not None:  # not where the drag shows a person (their rim the fit lies inside)
                fill = self._plate_learner.background_pixels(frame, fill, done, dragged, box)
            self.plate_region = self.plate.take(crop, fill, source, box, self.feather_width(projected))

    def _learn_plate(self, frame: np.ndarray, projected: np.ndarray, keep_mask: np.ndarray | None) -> float:
        """With the plate on: take ``frame`` into it outside the face (``projected`` (V, 2) px, its hull grown
        by PLATE_MARGIN of its size and ``dilate_px`` + 2), ``keep_mask`` and the people (``segmenter``); when
        the camera moves, the plate keeps the face's box grown by half its size; ms taken."""
        if self.plate is None:
            return 0.0
        t0 = time.perf_counter()
        self.plate_region = None
        keep_box, margin = None, self.dilate_px + 2.0
        if len(projected):
            lo, hi = point_bounds(projected)
            size = face_size(projected)
            margin = max(margin, PLATE_MARGIN * size)
            x0, y0 = np.floor(lo - 0.5 * size).astype(int)  # what the plate keeps when the camera moves
            x1, y1 = np.ceil(hi + 0.5 * size).astype(int)
            keep_box = (int(x0), int(y0), int(x1), int(y1))
        self._plate_learner.learn(frame, projected, margin, keep_box, keep_mask)
        return (time.perf_counter() - t0) * 1e3

    def prefetch(self, frame_bgr: np.ndarray) -> None:
        """Start the work of a frame that needs only the frame, before its face is fitted (the
        plate's people, :meth:`.PlateLearner.prefetch`); ``frame_bgr`` must reach :meth:`render`
        unchanged. Optional; nothing with the plate off."""
        if self._plate_learner is not None:
            self._plate_learner.prefetch(frame_bgr)

    def plate_sync(self) -> None:
        """Wait for the background plate's update of the last frame (it runs on a thread of its
        own from :meth:`render` until the fill needs it or the next frame starts)."""
        if self._plate_learner is not None:
            self._plate_learner.sync()

    @property
    def atlases(self) -> dict:
        """Face key -> its :class:`.texture_atlas.TextureAtlas` (empty with the atlas off)."""
        return self.memory.atlases if self.memory is not None else {}

    @property
    def atlas(self) -> TextureAtlas | None:
        """The last face's atlas (None with the atlas off)."""
        return self.memory.atlas if self.memory is not None else None

    def _update_memory(self, frame, fitted, projected, triangles, deformed, uv, face_key, keep_mask, P):
        """Step 6's inputs (``P`` (3, 4) the frame's camera): the atlas's per-vertex (u, v, quality)
        (:meth:`.AtlasMemory.update`) and,
        with keyframes on, (the keyframe chosen for the ``deformed`` view, its (V,) weights)
        (:mod:`.keyframe_views`) or None; the frame is then offered as a keyframe (not with a
        ``keep_mask``: a hand in front of the face would be kept with it)."""
        uvq = None if self.memory is None or uv is None else \
            self.memory.update(frame, fitted, projected, triangles, uv, face_key, keep_mask, P)
        self.keyframe_used = None
        if self.views is None:
            return uvq, None
        if face_key not in self.views and len(self.views) >= 8:
            self.views.clear()
        views = self.views.setdefault(face_key, KeyframeViews())
        raster = self._quality_raster or (self.memory.raster if uvq is None else None)
        quality = uvq[:, 2] if raster is None else raster.see(fitted, projected, np.asarray(triangles, np.int64), P)[0]
        key = views.choose(fitted, deformed)
        if keep_mask is None or not np.any(keep_mask):
            views.offer(frame, fitted, projected, quality)
        return uvq, None if key is None else (key, keyframe_weights(key.quality, quality))

    def _blend_memory(self, warped: np.ndarray, block: tuple[slice, slice], offsets: np.ndarray, changed: np.ndarray,
                      box: tuple[int, int, int, int], has_uv: bool, draw: tuple) -> None:
        """Blend the atlas (:meth:`_blend_atlas`), then the chosen keyframe
        (:func:`.keyframe_views.blend_keyframe`), into ``warped`` (the sampled ``block`` of the box, in
        place). ``draw``: (the fine vertices (Vf, >= 5), the triangles drawn, how many of them move,
        the keyframe choice of :meth:`_update_memory`)."""
        self._blend_atlas(warped, block, offsets, changed, box, has_uv)
        fine, draw_tris, n_moving, chosen = draw
        if chosen is not None:
            self.keyframe_used = blend_keyframe(warped, self.maps, self._mesh.S, fine, draw_tris, n_moving, box, block,
                                                changed, chosen, self.interpolation)

    def _extras(self, fine: np.ndarray) -> np.ndarray | None:
        """The source map's per-vertex extras: (Vf, 4) float32 (u, v, input frontality, 0) from the
        fine vertices' columns 5:8 (zeros without them); None with the atlas off."""
        if self.memory is None:
            return None
        extra = np.zeros((len(fine), 4), np.float32)
        if fine.shape[1] >= 8:
            extra[:, :3] = fine[:, 5:8]
        return extra

    def _blend_atlas(self, warped: np.ndarray, block: tuple[slice, slice], offsets: np.ndarray,
                     changed: np.ndarray, box: tuple[int, int, int, int], has_uv: bool) -> None:
        """Blend the atlas into ``warped`` (the sampled ``block`` of the box, (h', w', 3) uint8,
        in place) where the input sees the changed pixels' surface badly
        (:func:`.texture_atlas.blend_atlas`, with the source map's extras of ``box``). Nothing
        without ``has_uv`` or with ``atlas_blend`` off."""
        if not (has_uv and self.atlas_blend):
            return
        self.atlas_region = np.zeros(offsets.shape[:2], np.float32)
        self.atlas_region[block] = blend_atlas(warped, offsets[block], self.maps.read_extra(box)[block],
                                               changed[block], self.atlas)

    def _work_box(self, projected: np.ndarray, dst_px: np.ndarray, moved: np.ndarray,
                  head_motion: bool = False) -> tuple[int, int, int, int] | None:
        """The frame-pixel rectangle (x0, y0, x1, y1) the frame's work is done on: where the
        triangles within two rings of a moved vertex (``moved`` (V,) bool; subdivision spreads an
        offset that far) lie before and after (projected, dst_px (V, 2) pixels), with background
        around them for the fill and the soft edge, cut to the frame. None when less than 2 x 2
        pixels of it are in the frame. ``head_motion``: the head region around the face too
        (:func:`.motion_extension.head_box`); "body": and the body below it (:func:`.body_motion.body_box`)."""
        if head_motion:
            both = np.concatenate([projected, dst_px])
            box = head_box(both, self.width, self.height)
            return union_box(box, body_box(both, self.width, self.height)) if head_motion == "body" else box
        near = self._mesh.rings @ moved.astype(np.float32) > 0
        # background around the moved region: for the fill's context (FILL_CONTEXT_PX past what it
        # fills) and for the motion carried past the outline (the band) with its soft edge
        pad = self.dilate_px + max(FILL_CONTEXT_PX, int(np.ceil(self.feather_px)) + self.band_px(projected))
        both = np.concatenate([projected[near], dst_px[near]])
        lo, hi = point_bounds(both)
        lo, hi = np.floor(lo).astype(int) - pad, np.ceil(hi).astype(int) + pad + 1
        x0, y0 = max(0, lo[0]), max(0, lo[1])
        x1, y1 = min(self.width, hi[0]), min(self.height, hi[1])
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        return x0, y0, x1, y1

    def _masks(self, offsets: np.ndarray, orig_mask: np.ndarray, projected: np.ndarray):
        """The regions of the box: covered (deformed face, (h, w) bool), changed ((h, w) bool,
        covered with a non-negligible offset), the one to fill ((h, w) uint8 0/1: what the face
        no longer covers) and the (h, w) bool pixels the fill may take its colours from
        (background only), None when there is nothing to fill. ``orig_mask`` (h, w) uint8 0/1 is
        where the moving triangles were before the edit (the others do not move)."""
        covered = covered_pixels(offsets)
        changed = changed_pixels(offsets)
        fill = uncovered_mask(orig_mask, covered.view(np.uint8), self.dilate_px)
        if cv2.countNonZero(fill) == 0:
            return covered, changed, fill, None
        # The original face is where the moving triangles were plus where the face stays
        # (covered, not changed): the fill reads neither, nor a rim as wide as the fill grows
        # past the outline, plus a pixel (the outline's mixed pixels, a smoothed outline).
        face = orig_mask | (covered & ~changed).view(np.uint8)
        source = dilate(face, 1 + self.dilate_px) == 0
        source &= fill == 0
        if cv2.countNonZero(source.view(np.uint8)) == 0:  # the face fills the whole box: take what is outside the fill
            source = fill == 0
        return covered, changed, fill, source if cv2.countNonZero(source.view(np.uint8)) else None

    def band_px(self, projected: np.ndarray) -> int:
        """Pixels past the fitted outline a shape edit's motion reaches (``outline_band`` of the face's size)."""
        return int(round(self.outline_band * face_size(projected)))

    def feather_width(self, projected: np.ndarray) -> float:
        """Width (pixels) of the soft edge for a face at ``projected`` (V, 2) pixels: the larger
        of ``feather_px`` and FEATHER_FRACTION of the face's size (the geometric mean of its
        bounding box's sides); 0 when ``feather_px`` is 0."""
        if self.feather_px <= 0:
            return 0.0
        return max(self.feather_px, FEATHER_FRACTION * face_size(projected))

    def _composite(self, crop: np.ndarray, warped: np.ndarray, block: tuple[slice, slice],
                   offsets: np.ndarray, covered: np.ndarray, changed: np.ndarray, write: np.ndarray,
                   feather: float, fill: np.ndarray) -> None:
        """Blend the sampled face (``warped``, the (h', w', 3) uint8 ``block`` of the box) over the
        background ``crop`` (h, w, 3) uint8, in place, with a soft edge ``feather`` pixels wide
        inside the deformed outline, SILHOUETTE_FEATHER_PX beside the ``fill`` (h, w) uint8 (what
        the face uncovered); only the ``write`` pixels are written; then anti-alias the folds
        (changed pixels only)."""
        alpha = feather_alpha(covered.view(np.uint8), feather)
        if feather > SILHOUETTE_FEATHER_PX:
            sharpen_silhouette(alpha, cv2.subtract(fill, covered.view(np.uint8)), feather, SILHOUETTE_FEATHER_PX)
        alpha = alpha[block]
        part = crop[block]
        blended = cv2.blendLinear(warped, part, alpha, 1.0 - alpha)
        np.copyto(part, blended, where=write[block][..., None])
        fold = fold_edges(offsets[block], changed[block])
        if cv2.countNonZero(fold.view(np.uint8)):
            soften(part, fold, changed[block])

    def full_frame_regions(self) -> dict[str, np.ndarray]:
        """Full-frame (H, W) bool masks of the last render, within its box: 'original',
        'deformed', 'changed' (re-rendered: deformed with a non-negligible offset), 'inpainted'
        (all False when the last frame changed nothing)."""
        regions = {}
        for name, crop in (("original", self.original_region), ("deformed", self.deformed_region),
                           ("changed", self.changed_region), ("inpainted", self.inpainted_region)):
            full = np.zeros((self.height, self.width), bool)
            if crop is not None and self.box is not None:
                x0, y0, x1, y1 = self.box
                full[y0:y1, x0:x1] = crop != 0
            regions[name] = full
        return regions

    def release(self) -> None:
        """Free the GL objects (and the context when the compositor made it)."""
        if self.maps is not None:
            self.maps.release()
            self.maps = None
        if self._plate_learner is not None:
            self._plate_learner.close()
            self._plate_learner = None
        if self.memory is not None:
            self.memory.release()
            self.memory = None
        if self._quality_raster is not None:
            self._quality_raster.release()
            self._quality_raster = None
        if self._own_ctx and self.ctx is not None:
            self.ctx.release()
            self.ctx = None

    def __enter__(self) -> Compositor:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
