"""The compositor: one frame in, the frame with the deformed face out (docs/architecture.md "Stages", 4).

Per frame, on the bounding box of the face only:

1. the camera the fitter used is recovered from its (camera-space, pixel) vertex
   pairs (:mod:`.camera`), and the deformed vertices are projected with it;
2. the frame's face area is uploaded into a texture (a sub-rectangle write);
3. OpenGL (moderngl) draws the deformed mesh, textured with texture coordinates
   = the projection of the *undeformed* fitted mesh, into an offscreen RGBA
   target whose alpha is the deformed face region, and draws the undeformed
   mesh into an R8 target: the original face region. Both are read back for
   the bounding box only;
4. the background the face no longer covers (original minus deformed region,
   slightly dilated) is inpainted from the surrounding background (:mod:`.inpaint`),
   each connected part on its own small box;
5. the drawn face is blended over it with a feathered edge (alpha ramps from 0
   at the deformed outline to 1 ``feather_px`` inside), and the result is
   written into a copy of the frame at the pixels of the deformed region and
   the inpainted region only. Every other pixel is the input's, bit for bit,
   by construction.

Steps 4-5 run on the CPU: on llvmpipe a GPU pass would add an upload and a
readback of the same crop for work that numpy/OpenCV do cheaply on it
(benchmarks/bench_renderer.py measures both).
"""

from __future__ import annotations

import time

import cv2
import moderngl
import numpy as np

from .camera import estimate_projection, project
from .gl_context import create_headless_context
from .inpaint import INPAINT_METHODS, dilate, fill_by_parts, uncovered_mask
from .mesh import close_holes

_FACE_VS = """
#version 330
uniform vec4 u_box;        // x0, y0, w, h of the target in frame pixels
uniform vec2 u_tex_size;   // frame width, height
uniform vec2 u_depth;      // depth offset, 1 / depth range
in vec2 in_dst;            // deformed vertex, frame pixels (pixel centres at integers)
in float in_depth;         // grows away from the camera
in vec2 in_src;            // undeformed vertex, frame pixels: where its texture is
out vec2 v_uv;
void main() {
    vec2 ndc = (in_dst + 0.5 - u_box.xy) / u_box.zw * 2.0 - 1.0;
    float z = clamp((in_depth - u_depth.x) * u_depth.y, 0.0, 1.0) * 1.98 - 0.99;
    gl_Position = vec4(ndc, z, 1.0);
    v_uv = (in_src + 0.5) / u_tex_size;
}
"""

_FACE_FS = """
#version 330
uniform sampler2D u_frame;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(texture(u_frame, v_uv).rgb, 1.0);
}
"""

_MASK_VS = """
#version 330
uniform vec4 u_box;
in vec2 in_src;
void main() {
    gl_Position = vec4((in_src + 0.5 - u_box.xy) / u_box.zw * 2.0 - 1.0, 0.0, 1.0);
}
"""

_MASK_FS = """
#version 330
out float f_mask;
void main() {
    f_mask = 1.0;
}
"""


class Compositor:
    """Renders a deformed face into video frames of one size. Usable without the graph.

    Compositor(width, height, ctx=None, inpaint="pushpull", feather_px=3.0, dilate_px=2,
    telea_radius=3.0): frame size in pixels; ``ctx`` a moderngl context to draw with
    (default: a headless EGL context of its own); ``inpaint`` "pushpull" (fast) or
    "telea" (OpenCV); ``feather_px`` width of the soft edge inside the deformed outline;
    ``dilate_px`` growth of the region to inpaint (pixels).

    After each :meth:`render`, ``timings`` holds the stage times of that frame in ms
    (camera, texture, draw, readback, masks, inpaint, composite, total), ``box`` the
    frame-pixel rectangle (x0, y0, x1, y1) it worked on (None when nothing was drawn)
    and ``deformed_px`` the (V, 2) pixels of the deformed vertices.
    """

    def __init__(self, width: int, height: int, *, ctx: moderngl.Context | None = None,
                 inpaint: str = "pushpull", feather_px: float = 3.0, dilate_px: int = 2,
                 telea_radius: float = 3.0):
        width, height = int(width), int(height)
        if width <= 0 or height <= 0:
            raise ValueError(f"frame size must be positive, got {width}x{height}")
        if inpaint not in INPAINT_METHODS:
            raise ValueError(f"unknown inpaint method {inpaint!r} (known: {', '.join(INPAINT_METHODS)})")
        if feather_px < 0 or dilate_px < 0:
            raise ValueError("feather_px and dilate_px must be >= 0")
        self.width, self.height = width, height
        self.inpaint = inpaint
        self.feather_px = float(feather_px)
        self.dilate_px = int(dilate_px)
        self.telea_radius = float(telea_radius)
        self._own_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_headless_context()
        ctx = self.ctx
        self.texture = ctx.texture((width, height), 3, dtype="f1")
        self.texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.texture.repeat_x = self.texture.repeat_y = False
        self._face_color = ctx.renderbuffer((width, height), 4)
        self._face_depth = ctx.depth_renderbuffer((width, height))
        self.fbo_face = ctx.framebuffer([self._face_color], self._face_depth)
        self._orig_color = ctx.renderbuffer((width, height), 1)
        self.fbo_orig = ctx.framebuffer([self._orig_color])
        self.face_prog = ctx.program(vertex_shader=_FACE_VS, fragment_shader=_FACE_FS)
        self.mask_prog = ctx.program(vertex_shader=_MASK_VS, fragment_shader=_MASK_FS)
        self.face_prog["u_tex_size"].value = (float(width), float(height))
        self.face_prog["u_frame"].value = 0
        self._n_vertices = -1
        self._triangles_in: np.ndarray | None = None
        self._ibo = None
        self._n_indices = 0
        self.timings: dict[str, float] = {}
        self.box: tuple[int, int, int, int] | None = None
        # Crops of the last frame (box coordinates), for overlays and tests.
        self.original_region: np.ndarray | None = None
        self.deformed_region: np.ndarray | None = None
        self.inpainted_region: np.ndarray | None = None
        self.deformed_px: np.ndarray | None = None   # (V, 2) pixels of the last deformed mesh

    # -- geometry ----------------------------------------------------------------------------
    def _set_triangles(self, triangles: np.ndarray, n_vertices: int) -> None:
        tri = np.asarray(triangles)
        if (self._triangles_in is not None and tri.shape == self._triangles_in.shape
                and np.array_equal(tri, self._triangles_in) and n_vertices == self._n_vertices):
            return
        if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0:
            raise ValueError(f"triangles must be (T, 3) with T > 0, got {tri.shape}")
        if not np.issubdtype(tri.dtype, np.integer):
            raise ValueError(f"triangles must be integer indices, got {tri.dtype}")
        if tri.min() < 0 or tri.max() >= n_vertices:
            raise ValueError(f"triangle indices must lie in [0, {n_vertices}), got [{tri.min()}, {tri.max()}]")
        closed = close_holes(tri).astype(np.uint32)
        if self._ibo is not None:
            self._ibo.release()
        self._ibo = self.ctx.buffer(closed.tobytes())
        self._n_indices = closed.size
        self._triangles_in = tri.copy()
        if n_vertices != self._n_vertices:
            for name in ("_vbo_dst", "_vbo_src"):
                old = getattr(self, name, None)
                if old is not None:
                    old.release()
            self._vbo_dst = self.ctx.buffer(reserve=n_vertices * 3 * 4)
            self._vbo_src = self.ctx.buffer(reserve=n_vertices * 2 * 4)
            self._n_vertices = n_vertices
        for name in ("_vao_face", "_vao_mask"):
            old = getattr(self, name, None)
            if old is not None:
                old.release()
        self._vao_face = self.ctx.vertex_array(
            self.face_prog, [(self._vbo_dst, "2f 1f", "in_dst", "in_depth"), (self._vbo_src, "2f", "in_src")],
            index_buffer=self._ibo)
        self._vao_mask = self.ctx.vertex_array(self.mask_prog, [(self._vbo_src, "2f", "in_src")],
                                               index_buffer=self._ibo)

    def _check(self, frame, fitted, projected, deformed):
        if not (isinstance(frame, np.ndarray) and frame.dtype == np.uint8
                and frame.shape == (self.height, self.width, 3)):
            got = f"{frame.shape} {frame.dtype}" if isinstance(frame, np.ndarray) else type(frame).__name__
            raise ValueError(f"frame must be ({self.height}, {self.width}, 3) uint8 BGR, got {got}")
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

    def deformed_pixels(self, fitted_vertices, projected_px, deformed_vertices):
        """Pixels (V, 2) float64 and depth (V,) float64 of the deformed vertices.

        The camera is recovered from the (fitted_vertices, projected_px) pairs; the pixels
        are projected_px moved by the projected displacement, so zero deformation gives
        projected_px exactly.
        """
        P = estimate_projection(fitted_vertices, projected_px)
        V = len(fitted_vertices)
        px, depth = project(P, np.concatenate([fitted_vertices, deformed_vertices]))  # one pass
        return projected_px + (px[V:] - px[:V]), depth[V:]

    # -- the frame ---------------------------------------------------------------------------
    def render(self, frame_bgr: np.ndarray, fitted_vertices: np.ndarray, projected_px: np.ndarray,
               triangles: np.ndarray, deformed_vertices: np.ndarray) -> np.ndarray:
        """The frame with the face replaced by its deformed version.

        frame_bgr: (H, W, 3) uint8, the frame the face was fitted on (not modified).
        fitted_vertices: (V, 3) float, the fitted (undeformed) mesh in camera space (any units).
        projected_px: (V, 2) float, its projection into the frame, pixels (OpenCV convention:
            pixel centres at integer coordinates); the texture coordinates.
        triangles: (T, 3) int vertex indices of the mesh (holes are closed internally).
        deformed_vertices: (V, 3) float, the deformed mesh in the same camera space
            (Eq. 5: fitted + the edit rotated and scaled into the head pose).
        V = 0 (no face) returns a copy of the frame. Returns a new (H, W, 3) uint8 frame; outside the union of the original and deformed
        face regions (grown by ``dilate_px``) it equals ``frame_bgr`` exactly.
        Raises ValueError on inputs of the wrong shape, type or size.
        """
        t_start = time.perf_counter()
        fitted, projected, deformed = self._check(frame_bgr, fitted_vertices, projected_px, deformed_vertices)
        self.box = None
        self.original_region = self.deformed_region = self.inpainted_region = None
        self.deformed_px = None
        V = fitted.shape[0]
        if V == 0:  # no face
            self.timings = {"total": (time.perf_counter() - t_start) * 1e3}
            return frame_bgr.copy()
        self._set_triangles(triangles, V)
        t0 = time.perf_counter()
        dst_px, depth = self.deformed_pixels(fitted, projected, deformed)
        self.deformed_px = dst_px
        t_camera = time.perf_counter() - t0

        out = frame_bgr.copy()
        box = self._work_box(projected, dst_px)
        if box is None:
            self.timings = {"camera": t_camera * 1e3, "total": (time.perf_counter() - t_start) * 1e3}
            return out  # the face is entirely outside the frame
        x0, y0, x1, y1 = box
        t0 = time.perf_counter()
        self._upload_texture(frame_bgr, projected)
        t1 = time.perf_counter()
        self._draw(dst_px, depth, projected, box)
        t2 = time.perf_counter()
        rgba, orig = self._read_back(box)
        t3 = time.perf_counter()
        orig_mask, def_mask, fill, source = self._masks(rgba, orig)
        t4 = time.perf_counter()
        crop = out[y0:y1, x0:x1]
        if source is not None:  # in place: the crop becomes the background (the face is blended over it below)
            fill_by_parts(crop, fill, source, self.inpaint, radius=self.telea_radius, in_place=True)
        t5 = time.perf_counter()
        self._composite(crop, rgba, def_mask, fill)
        t6 = time.perf_counter()

        self.box = box
        self.original_region, self.deformed_region, self.inpainted_region = orig_mask, def_mask, fill
        self.timings = {
            "camera": t_camera * 1e3, "texture": (t1 - t0) * 1e3, "draw": (t2 - t1) * 1e3,
            "readback": (t3 - t2) * 1e3, "masks": (t4 - t3) * 1e3, "inpaint": (t5 - t4) * 1e3,
            "composite": (t6 - t5) * 1e3,
            "total": (time.perf_counter() - t_start) * 1e3,
        }
        return out

    def _work_box(self, projected: np.ndarray, dst_px: np.ndarray) -> tuple[int, int, int, int] | None:
        """The frame-pixel rectangle (x0, y0, x1, y1) the frame's work is done on: both face
        regions (projected (V, 2), dst_px (V, 2) pixels) with background around them for the
        fill, cut to the frame. None when less than 2 x 2 pixels of it are in the frame."""
        pad = self.dilate_px + 10  # background context around the region for the fill
        both = np.concatenate([projected, dst_px])
        lo = np.floor(both.min(axis=0)).astype(int) - pad
        hi = np.ceil(both.max(axis=0)).astype(int) + pad + 1
        x0, y0 = max(0, lo[0]), max(0, lo[1])
        x1, y1 = min(self.width, hi[0]), min(self.height, hi[1])
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        return x0, y0, x1, y1

    def _upload_texture(self, frame_bgr: np.ndarray, projected: np.ndarray) -> None:
        """Write into the texture the part of the frame the undeformed mesh (projected (V, 2)
        pixels) covers, +1 px for filtering."""
        W, H = self.width, self.height
        slo = np.clip(np.floor(projected.min(axis=0)).astype(int) - 2, 0, [W, H])
        shi = np.clip(np.ceil(projected.max(axis=0)).astype(int) + 3, 0, [W, H])
        if (shi - slo).min() > 0:
            sub = np.ascontiguousarray(frame_bgr[slo[1]:shi[1], slo[0]:shi[0]])
            self.texture.write(sub, viewport=(int(slo[0]), int(slo[1]), int(shi[0] - slo[0]), int(shi[1] - slo[1])))

    def _draw(self, dst_px: np.ndarray, depth: np.ndarray, projected: np.ndarray,
              box: tuple[int, int, int, int]) -> None:
        """Draw the deformed face (dst_px (V, 2) pixels, depth (V,)) textured at ``projected``
        (V, 2) pixels into ``fbo_face``, and the original region into ``fbo_orig``, both at
        the origin of their targets, ``box`` in size."""
        x0, y0, x1, y1 = box
        bw, bh = x1 - x0, y1 - y0
        dmin, dmax = float(depth.min()), float(depth.max())
        drange = max(dmax - dmin, 1e-9)
        self._vbo_dst.write(np.column_stack([dst_px, depth]).astype(np.float32).tobytes())
        self._vbo_src.write(projected.astype(np.float32).tobytes())
        box_uniform = (float(x0), float(y0), float(bw), float(bh))
        self.face_prog["u_box"].value = box_uniform
        self.face_prog["u_depth"].value = (dmin - 0.01 * drange, 1.0 / (1.02 * drange))
        self.mask_prog["u_box"].value = box_uniform
        ctx = self.ctx
        viewport = (0, 0, bw, bh)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        self.fbo_face.use()
        ctx.viewport = viewport
        ctx.enable(moderngl.DEPTH_TEST)
        self.fbo_face.clear(0.0, 0.0, 0.0, 0.0, depth=1.0, viewport=viewport)
        self.texture.use(0)
        self._vao_face.render(moderngl.TRIANGLES, vertices=self._n_indices)
        ctx.disable(moderngl.DEPTH_TEST)
        self.fbo_orig.use()
        ctx.viewport = viewport
        self.fbo_orig.clear(0.0, viewport=viewport)
        self._vao_mask.render(moderngl.TRIANGLES, vertices=self._n_indices)

    def _read_back(self, box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The drawn face (h, w, 4) uint8 BGRA (alpha: the deformed region) and the original
        region (h, w) uint8, both 0 or 255, ``box`` in size."""
        x0, y0, x1, y1 = box
        bw, bh = x1 - x0, y1 - y0
        viewport = (0, 0, bw, bh)
        rgba = np.frombuffer(self.fbo_face.read(viewport=viewport, components=4, alignment=1),
                             np.uint8).reshape(bh, bw, 4)
        orig = np.frombuffer(self.fbo_orig.read(viewport=viewport, components=1, alignment=1),
                             np.uint8).reshape(bh, bw)
        return rgba, orig

    def _masks(self, rgba: np.ndarray, orig: np.ndarray):
        """The regions as (h, w) uint8 0/1 masks: original, deformed, and the one to fill (what
        the face no longer covers), with the (h, w) bool pixels the fill may take its colours
        from (background only), None when there is nothing to fill."""
        orig_mask = orig >> 7  # the targets hold exactly 0 or 255
        def_mask = rgba[..., 3] >> 7
        fill = uncovered_mask(orig_mask, def_mask, self.dilate_px)
        if cv2.countNonZero(fill) == 0:
            return orig_mask, def_mask, fill, None
        source = dilate(orig_mask, 1) == 0
        source &= fill == 0
        if not source.any():  # the face fills the whole box: take what is outside the fill
            source = fill == 0
        return orig_mask, def_mask, fill, source if source.any() else None

    def _composite(self, crop: np.ndarray, rgba: np.ndarray, def_mask: np.ndarray, fill: np.ndarray) -> None:
        """Blend the drawn face (rgba (h, w, 4)) over the background ``crop`` (h, w, 3) uint8,
        in place, with a feathered outline; only the deformed and filled pixels are written."""
        if self.feather_px > 0:
            alpha = cv2.distanceTransform(def_mask, cv2.DIST_L2, 3)
            alpha *= 1.0 / self.feather_px
            np.minimum(alpha, 1.0, out=alpha)
        else:
            alpha = def_mask.astype(np.float32)
        face = cv2.cvtColor(rgba, cv2.COLOR_BGRA2BGR)  # a contiguous copy of the colour
        blended = cv2.blendLinear(face, crop, alpha, 1.0 - alpha)
        write = (def_mask | fill).astype(bool)
        np.copyto(crop, blended, where=write[..., None])

    def full_frame_regions(self) -> dict[str, np.ndarray]:
        """Full-frame (H, W) bool masks of the last render: 'original', 'deformed', 'inpainted'
        (all False when the last frame drew nothing)."""
        regions = {}
        for name, crop in (("original", self.original_region), ("deformed", self.deformed_region),
                           ("inpainted", self.inpainted_region)):
            full = np.zeros((self.height, self.width), bool)
            if crop is not None and self.box is not None:
                x0, y0, x1, y1 = self.box
                full[y0:y1, x0:x1] = crop != 0
            regions[name] = full
        return regions

    def release(self) -> None:
        """Free the GL objects (and the context when the compositor made it)."""
        for name in ("_vao_face", "_vao_mask", "_vbo_dst", "_vbo_src", "_ibo", "fbo_face", "fbo_orig",
                     "_face_color", "_face_depth", "_orig_color", "texture", "face_prog", "mask_prog"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
        if self._own_ctx and self.ctx is not None:
            self.ctx.release()
            self.ctx = None

    def __enter__(self) -> Compositor:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
