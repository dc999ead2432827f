"""Where each output pixel's colour comes from: the source map, rasterised with OpenGL (moderngl).

The deformed mesh is drawn (z-buffered) with, as a per-vertex attribute, the offset from its
deformed pixel back to its undeformed one (``d = source - destination``, pixels). Interpolated
over each triangle without perspective, the offset at a pixel p says where in the input
frame p's colour is: ``p + d(p)``. Drawing the offset rather than the source position keeps a
zero offset exactly zero (every vertex 0, so every interpolated value 0), whatever the
rasteriser's sub-pixel snapping, so pixels that do not move can be recognised exactly.

The target is RG32F, cleared to :data:`UNCOVERED` (no triangle there). A second pass draws the
moving part of the mesh undeformed (its pixels ``dst + d``) into an R8 target: where the moving
face was (the rest of the face does not move). Both are read back for the work box only (the
targets are as large as the largest box so far, and cleared whole). The colours are sampled
afterwards on the CPU, once (:mod:`.warp`), so no frame texture, mipmap or second resampling is involved.
"""

from __future__ import annotations

import moderngl
import numpy as np

UNCOVERED = 1.0e9  # the clear value of the offset target: no triangle drew this pixel
TARGET_STEP = 64   # the targets grow in steps of this many pixels

_MAP_VS = """
#version 330
uniform vec4 u_box;        // x0, y0, w, h of the target in frame pixels
uniform vec2 u_depth;      // depth offset, 1 / depth range
in vec2 in_dst;            // deformed vertex, frame pixels (pixel centres at integers)
in float in_depth;         // grows away from the camera
in vec2 in_offset;         // undeformed minus deformed pixel position
noperspective out vec2 v_offset;
void main() {
    vec2 ndc = (in_dst + 0.5 - u_box.xy) / u_box.zw * 2.0 - 1.0;
    float z = clamp((in_depth - u_depth.x) * u_depth.y, 0.0, 1.0) * 1.98 - 0.99;
    gl_Position = vec4(ndc, z, 1.0);
    v_offset = in_offset;
}
"""

_MAP_FS = """
#version 330
noperspective in vec2 v_offset;
out vec2 f_offset;
void main() {
    f_offset = v_offset;
}
"""

# The same with per-vertex extras (e.g. texture coordinates) written to a second target.
_MAP_EXTRA_VS = _MAP_VS.replace("in vec2 in_offset;", "in vec2 in_offset;\nin vec4 in_extra;\nnoperspective out vec4 v_extra;") \
    .replace("v_offset = in_offset;", "v_offset = in_offset;\n    v_extra = in_extra;")
_MAP_EXTRA_FS = """
#version 330
noperspective in vec2 v_offset;
noperspective in vec4 v_extra;
layout(location = 0) out vec2 f_offset;
layout(location = 1) out vec4 f_extra;
void main() {
    f_offset = v_offset;
    f_extra = v_extra;
}
"""

_MASK_VS = """
#version 330
uniform vec4 u_box;
in vec2 in_dst;
in vec2 in_offset;
void main() {
    gl_Position = vec4((in_dst + in_offset + 0.5 - u_box.xy) / u_box.zw * 2.0 - 1.0, 0.0, 1.0);
}
"""

_MASK_FS = """
#version 330
out float f_mask;
void main() {
    f_mask = 1.0;
}
"""


class SourceMapRenderer:
    """Draws the offset map and the original region of a mesh into targets of one frame size.

    SourceMapRenderer(ctx, width, height, extras=False): ``ctx`` a moderngl context; ``width`` x
    ``height`` the frame's pixels (the targets grow with the boxes drawn, up to that); ``extras``: also
    interpolate four floats per vertex (:meth:`draw`'s ``extra``) into a second target
    (:meth:`read_extra`). :meth:`set_mesh` once per mesh size, :meth:`draw` per frame,
    :meth:`release` at the end.
    """

    def __init__(self, ctx: moderngl.Context, width: int, height: int, extras: bool = False):
        self.ctx = ctx
        self.extras = bool(extras)
        self.width, self.height = int(width), int(height)
        self.target_size = (0, 0)   # the targets' size (px): the largest box drawn so far, rounded up
        self._map_color = self._map_depth = self._extra_color = self.fbo_map = None
        self._orig_color = self.fbo_orig = None
        if self.extras:
            self.map_prog = ctx.program(vertex_shader=_MAP_EXTRA_VS, fragment_shader=_MAP_EXTRA_FS)
        else:
            self.map_prog = ctx.program(vertex_shader=_MAP_VS, fragment_shader=_MAP_FS)
        self.mask_prog = ctx.program(vertex_shader=_MASK_VS, fragment_shader=_MASK_FS)
        self._vbo = self._ibo = self._vao_map = self._vao_mask = self._vbo_extra = None
        self._n_vertices = self._vertex_room = self._max_triangles = 0

    def _fit_targets(self, bw: int, bh: int) -> None:
        """Targets at least ``bw`` x ``bh`` px (a box's), grown in steps of TARGET_STEP px up to the
        frame's size. Targets as small as the box are cleared whole, which llvmpipe does without
        drawing (a clear of part of a target is a drawn rectangle), and cost no memory for the
        rest of the frame."""
        tw, th = self.target_size
        if bw <= tw and bh <= th:
            return
        tw = min(max(tw, -(-bw // TARGET_STEP) * TARGET_STEP), max(self.width, bw))
        th = min(max(th, -(-bh // TARGET_STEP) * TARGET_STEP), max(self.height, bh))
        self._release_targets()
        ctx = self.ctx
        self._map_color = ctx.renderbuffer((tw, th), 2, dtype="f4")
        self._map_depth = ctx.depth_renderbuffer((tw, th))
        self._extra_color = ctx.renderbuffer((tw, th), 4, dtype="f4") if self.extras else None
        attachments = [self._map_color] + ([self._extra_color] if self.extras else [])
        self.fbo_map = ctx.framebuffer(attachments, self._map_depth)
        self._orig_color = ctx.renderbuffer((tw, th), 1)
        self.fbo_orig = ctx.framebuffer([self._orig_color])
        self.target_size = (tw, th)

    def _release_targets(self) -> None:
        for name in ("fbo_map", "fbo_orig", "_map_color", "_extra_color", "_map_depth", "_orig_color"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)

    def set_mesh(self, n_vertices: int, max_triangles: int) -> None:
        """Make room for meshes of ``n_vertices`` vertices and up to ``max_triangles`` triangles
        (the buffers are kept when they are large enough: meshes may change from frame to frame)."""
        if 0 < n_vertices <= self._vertex_room and max_triangles <= self._max_triangles:
            self._n_vertices = int(n_vertices)
            return
        for name in ("_vao_map", "_vao_mask", "_vbo", "_ibo", "_vbo_extra"):
            old = getattr(self, name)
            if old is not None:
                old.release()
        self._ibo = self.ctx.buffer(reserve=max(int(max_triangles), 1) * 3 * 4)
        self._vbo = self.ctx.buffer(reserve=max(int(n_vertices), 1) * 5 * 4)
        self._n_vertices = self._vertex_room = int(n_vertices)
        self._max_triangles = int(max_triangles)
        buffers = [(self._vbo, "2f 1f 2f", "in_dst", "in_depth", "in_offset")]
        if self.extras:
            self._vbo_extra = self.ctx.buffer(reserve=max(int(n_vertices), 1) * 4 * 4)
            buffers.append((self._vbo_extra, "4f", "in_extra"))
        self._vao_map = self.ctx.vertex_array(self.map_prog, buffers, index_buffer=self._ibo)
        self._vao_mask = self.ctx.vertex_array(
            self.mask_prog, [(self._vbo, "2f 4x 2f", "in_dst", "in_offset")], index_buffer=self._ibo)

    def draw(self, dst_px: np.ndarray, depth: np.ndarray, offset: np.ndarray, triangles: np.ndarray,
             n_original: int, box: tuple[int, int, int, int], extra: np.ndarray | None = None) -> None:
        """Rasterise a mesh in ``box`` (x0, y0, x1, y1 frame pixels), at the origin of the
        targets; :meth:`read` reads it back.

        dst_px: (V, 2) deformed vertex pixels; depth: (V,) growing away from the camera;
        offset: (V, 2) undeformed minus deformed pixels; triangles: (T, 3) int into them, all
        drawn into the offset map, the first ``n_original`` of them into the original region;
        extra: (V, 4) float per vertex for the extras target (renderers made with ``extras``;
        None: zeros).
        """
        tri = np.ascontiguousarray(triangles, np.uint32)
        if len(tri) > self._max_triangles:
            raise ValueError(f"{len(tri)} triangles, room for {self._max_triangles}")
        self._ibo.write(tri.tobytes())
        x0, y0, x1, y1 = box
        bw, bh = x1 - x0, y1 - y0
        self._fit_targets(bw, bh)
        dmin, dmax = float(depth.min()), float(depth.max())
        drange = max(dmax - dmin, 1e-9)
        data = np.empty((self._n_vertices, 5), np.float32)
        data[:, 0:2] = dst_px
        data[:, 2] = depth
        data[:, 3:5] = offset
        self._vbo.write(data.tobytes())
        if self.extras:
            ext = np.zeros((self._n_vertices, 4), np.float32) if extra is None else extra
            self._vbo_extra.write(np.ascontiguousarray(ext, np.float32).tobytes())
        box_uniform = (float(x0), float(y0), float(bw), float(bh))
        self.map_prog["u_box"].value = box_uniform
        self.map_prog["u_depth"].value = (dmin - 0.01 * drange, 1.0 / (1.02 * drange))
        self.mask_prog["u_box"].value = box_uniform
        ctx = self.ctx
        viewport = (0, 0, bw, bh)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        self.fbo_map.use()
        ctx.viewport = viewport
        ctx.enable(moderngl.DEPTH_TEST)
        self.fbo_map.clear(UNCOVERED, UNCOVERED, 0.0, 0.0, depth=1.0)  # every attachment, whole
        self._vao_map.render(moderngl.TRIANGLES, vertices=3 * len(tri))
        ctx.disable(moderngl.DEPTH_TEST)
        self.fbo_orig.use()
        ctx.viewport = viewport
        self.fbo_orig.clear(0.0)
        if n_original > 0:
            self._vao_mask.render(moderngl.TRIANGLES, vertices=3 * int(n_original))

    def read(self, box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The last :meth:`draw`, ``box`` in size: (offset map (h, w, 2) float32, pixels;
        :data:`UNCOVERED` where no triangle is; original region (h, w) uint8 0/1)."""
        x0, y0, x1, y1 = box
        bw, bh = x1 - x0, y1 - y0
        viewport = (0, 0, bw, bh)
        offsets = np.frombuffer(self.fbo_map.read(viewport=viewport, components=2, dtype="f4", alignment=1),
                                np.float32).reshape(bh, bw, 2)
        orig = np.frombuffer(self.fbo_orig.read(viewport=viewport, components=1, alignment=1),
                             np.uint8).reshape(bh, bw)
        return offsets, orig >> 7  # the mask target holds exactly 0 or 255

    def read_extra(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """The extras of the last :meth:`draw`, ``box`` in size: (h, w, 4) float32 (UNCOVERED in
        the first two where no triangle is)."""
        x0, y0, x1, y1 = box
        bw, bh = x1 - x0, y1 - y0
        return np.frombuffer(self.fbo_map.read(viewport=(0, 0, bw, bh), components=4, dtype="f4", alignment=1,
                                               attachment=1), np.float32).reshape(bh, bw, 4)

    def release(self) -> None:
        """Free the GL objects."""
        self._release_targets()
        for name in ("_vao_map", "_vao_mask", "_vbo", "_ibo", "_vbo_extra", "map_prog", "mask_prog"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
