"""What one frame shows of a face's UV atlas, rasterised with OpenGL (moderngl): the inputs of
:class:`.texture_atlas.TextureAtlas` (issue 16; docs/architecture.md "Stages", 4).

Two passes per frame, over the fitted (undeformed) mesh:

1. **view depth**: the mesh drawn in the frame (the face's box only), z-buffered, writing its
   depth: what the camera sees;
2. **UV space**: the mesh drawn at its texture coordinates into an (S, S) target, each texel
   getting the frame pixel its surface point projects to, that point's depth and the
   frontality of the surface there (cosine of the vertex normals with the view ray,
   interpolated).

On the CPU: a texel is visible where its depth is within a tolerance of the view depth at its
pixel; its size is the square root of the frame-pixel area one texel covers (from the pixel
map's differences); its quality is frontality x min(size, 1), 0 where hidden or back-facing, and
0 within ``EDGE_PX`` of an occluding edge of the view (the projected mesh edges between a
triangle that faces the camera and one that does not, and the mesh's open borders: the face's
outline, the nose's side): there a fitted mesh that is off by a pixel or two samples the other side of
the edge (background, the ridge's highlight), which the atlas would keep as a ghost.
Per vertex the same visibility and frontality (:attr:`AtlasRasterizer.vertex_quality`) say how
well the frame sees each vertex: the compositor takes the atlas where that is poor.
"""

from __future__ import annotations

import cv2
import moderngl
import numpy as np

from facesculpt.geometry import point_bounds
from facesculpt.geometry.vertex_normals import face_normals, vertex_normals

from .camera import project

_VIEW_VS = """
#version 330
uniform vec4 u_box;     // x0, y0, w, h of the target in frame pixels
uniform vec2 u_depth;   // depth offset, 1 / depth range
in vec2 in_px;
in float in_depth;
out float v_depth;
void main() {
    float z = clamp((in_depth - u_depth.x) * u_depth.y, 0.0, 1.0) * 1.98 - 0.99;
    gl_Position = vec4((in_px + 0.5 - u_box.xy) / u_box.zw * 2.0 - 1.0, z, 1.0);
    v_depth = in_depth;
}
"""

_VIEW_FS = """
#version 330
in float v_depth;
out float f_depth;
void main() { f_depth = v_depth; }
"""

_UV_VS = """
#version 330
in vec2 in_uv;
in vec2 in_px;
in float in_depth;
in float in_cos;
noperspective out vec4 v_obs;
void main() {
    gl_Position = vec4(in_uv * 2.0 - 1.0, 0.0, 1.0);
    v_obs = vec4(in_px, in_depth, in_cos);
}
"""

_UV_FS = """
#version 330
noperspective in vec4 v_obs;
out vec4 f_obs;
void main() { f_obs = v_obs; }
"""

FAR = 1.0e30          # clear value of the view depth: nothing drawn there
DEPTH_TOLERANCE = 0.02  # share of the mesh's extent a texel may lie behind the visible surface
EDGE_PX = 3             # texels seen this close to an occluding edge (frame pixels) are not taken


def camera_centre(P: np.ndarray) -> np.ndarray:
    """The centre of the (3, 4) projection ``P``: its null vector (4,), homogeneous; its last
    coordinate is 0 for a camera at infinity (affine: orthographic, scaled orthographic), whose
    first three then give the direction of its viewing rays (up to sign)."""
    _, _, vt = np.linalg.svd(np.asarray(P, np.float64))
    return vt[-1]


def vertex_frontality(vertices: np.ndarray, triangles: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(V,) float32: the cosine between each vertex's normal (area-weighted over its triangles)
    and the direction to the camera of ``P`` (3, 4); the normals are oriented so that most of the
    surface faces the camera (a face is seen from its front). ``vertices`` (V, 3), ``triangles``
    (T, 3) int."""
    X = np.asarray(vertices, np.float64)
    tri = np.asarray(triangles, np.int64)
    fn = face_normals(X, tri)
    n = vertex_normals(X, tri, fn)
    c = camera_centre(P)
    if abs(c[3]) < 1e-12:   # at infinity: every ray runs along the centre's direction
        to_cam = np.broadcast_to(c[:3], X.shape)
    else:
        to_cam = c[:3] / c[3] - X
    to_cam = to_cam / np.maximum(np.linalg.norm(to_cam, axis=1, keepdims=True), 1e-12)
    cos = np.einsum("ij,ij->i", n, to_cam)
    area = np.linalg.norm(fn, axis=1)
    tri_cos = cos[tri].mean(axis=1)
    if float((tri_cos * area).sum()) < 0:
        cos = -cos
    return cos.astype(np.float32)


class AtlasRasterizer:
    """AtlasRasterizer(ctx, size, width, height): ``ctx`` a moderngl context, atlas ``size``
    texels a side, frames ``width`` x ``height`` pixels. :meth:`observe` per frame,
    :meth:`release` at the end."""

    def __init__(self, ctx: moderngl.Context, size: int, width: int, height: int):
        self.ctx, self.size, self.width, self.height = ctx, int(size), int(width), int(height)
        self._view_color = ctx.renderbuffer((self.width, self.height), 1, dtype="f4")
        self._view_depth = ctx.depth_renderbuffer((self.width, self.height))
        self.fbo_view = ctx.framebuffer([self._view_color], self._view_depth)
        self._uv_color = ctx.renderbuffer((self.size, self.size), 4, dtype="f4")
        self.fbo_uv = ctx.framebuffer([self._uv_color])
        self.view_prog = ctx.program(vertex_shader=_VIEW_VS, fragment_shader=_VIEW_FS)
        self.uv_prog = ctx.program(vertex_shader=_UV_VS, fragment_shader=_UV_FS)
        self.vertex_quality: np.ndarray | None = None   # (V,) float32 of the last observe/see

    def _view_depth_map(self, px, depth, tri) -> tuple[np.ndarray, tuple[int, int, int, int]] | None:
        """The mesh's depth as the frame sees it, over its box: ((h, w) float32, FAR where empty;
        box (x0, y0, x1, y1)); None when the mesh is not in the frame."""
        lo, hi = point_bounds(px)
        lo, hi = np.floor(lo).astype(int) - 1, np.ceil(hi).astype(int) + 2
        x0, y0 = max(0, lo[0]), max(0, lo[1])
        x1, y1 = min(self.width, hi[0]), min(self.height, hi[1])
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        ctx, bw, bh = self.ctx, x1 - x0, y1 - y0
        data = np.column_stack([px, depth]).astype(np.float32)
        vbo = ctx.buffer(data.tobytes())
        ibo = ctx.buffer(np.ascontiguousarray(tri, np.uint32).tobytes())
        vao = ctx.vertex_array(self.view_prog, [(vbo, "2f 1f", "in_px", "in_depth")], index_buffer=ibo)
        dmin, drange = float(depth.min()), max(float(np.ptp(depth)), 1e-9)
        self.view_prog["u_box"].value = (float(x0), float(y0), float(bw), float(bh))
        self.view_prog["u_depth"].value = (dmin - 0.01 * drange, 1.0 / (1.02 * drange))
        self.fbo_view.use()
        ctx.viewport = (0, 0, bw, bh)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        ctx.enable(moderngl.DEPTH_TEST)
        self.fbo_view.clear(FAR, depth=1.0, viewport=(0, 0, bw, bh))
        vao.render(moderngl.TRIANGLES)
        ctx.disable(moderngl.DEPTH_TEST)
        view = np.frombuffer(self.fbo_view.read(viewport=(0, 0, bw, bh), components=1, dtype="f4", alignment=1),
                             np.float32).reshape(bh, bw)
        for obj in (vao, vbo, ibo):
            obj.release()
        return view, (x0, y0, x1, y1)

    @staticmethod
    def _visible(view, box, px, depth, tol) -> np.ndarray:
        """(N,) bool: points at ``px`` (N, 2) with ``depth`` (N,) no more than ``tol`` behind the
        view depth there (the smallest of the 2 x 2 pixels around each point)."""
        x0, y0 = box[0], box[1]
        h, w = view.shape
        ix = np.clip(np.floor(px[:, 0]).astype(np.int64) - x0, 0, w - 2)
        iy = np.clip(np.floor(px[:, 1]).astype(np.int64) - y0, 0, h - 2)
        near = np.minimum(np.minimum(view[iy, ix], view[iy, ix + 1]), np.minimum(view[iy + 1, ix], view[iy + 1, ix + 1]))
        return depth <= near + tol

    def _edges(self, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mesh's edges (E, 2) and their two triangles (E, 2) (-1: an open border), kept per
        triangle set."""
        tri = np.asarray(triangles, np.int64)
        key = (tri.shape, hash(tri.tobytes()))
        if getattr(self, "_edge_key", None) != key:
            e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
            owner = np.tile(np.arange(len(tri)), 3)
            uniq, first, inv = np.unique(e, axis=0, return_index=True, return_inverse=True)
            sides = np.full((len(uniq), 2), -1, np.int64)
            sides[:, 0] = owner[first]
            other = np.ones(len(e), bool)
            other[first] = False
            sides[inv.ravel()[other], 1] = owner[other]
            self._edge_key, self._edge_data = key, (uniq, sides)
        return self._edge_data

    def _near_edge(self, box, px, triangles, points) -> np.ndarray:
        """(N,) bool: ``points`` (N, 2) frame pixels within EDGE_PX of an occluding edge of the
        mesh at ``px`` (V, 2) (its projected triangles' orientation changes across the edge, or
        the edge is an open border), drawn over ``box``."""
        edges, sides = self._edges(triangles)
        tri = np.asarray(triangles, np.int64)
        a, b, c = px[tri[:, 0]], px[tri[:, 1]], px[tri[:, 2]]
        facing = ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) > 0
        f0 = facing[sides[:, 0]]
        f1 = np.where(sides[:, 1] >= 0, facing[np.maximum(sides[:, 1], 0)], ~f0)
        occluding = edges[f0 != f1]
        x0, y0, x1, y1 = box
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        lines = np.rint((px[occluding] - [x0, y0]) * 4).astype(np.int32)   # 2 fractional bits
        cv2.polylines(mask, list(lines), False, 1, thickness=2 * EDGE_PX + 1, shift=2)
        h, w = mask.shape
        ix = np.clip(np.rint(points[:, 0]).astype(np.int64) - x0, 0, w - 1)
        iy = np.clip(np.rint(points[:, 1]).astype(np.int64) - y0, 0, h - 1)
        return mask[iy, ix] != 0

    def see(self, vertices: np.ndarray, px: np.ndarray, triangles: np.ndarray, P: np.ndarray):
        """Per vertex, how well the frame sees it: sets and returns :attr:`vertex_quality` (V,)
        float32 (frontality, 0 where hidden or back-facing) and returns the view depth map, its
        box, the vertices' depth and the depth tolerance for :meth:`observe`. ``vertices`` (V, 3)
        camera space, ``px`` (V, 2) their pixels, ``triangles`` (T, 3), ``P`` (3, 4) the camera."""
        px = np.asarray(px, np.float64)
        _, depth = project(P, np.asarray(vertices, np.float64))
        cos = vertex_frontality(vertices, triangles, P)
        got = self._view_depth_map(px, depth, triangles)
        if got is None:
            self.vertex_quality = np.zeros(len(px), np.float32)
            return self.vertex_quality, None, None, depth, cos, 0.0
        view, box = got
        tol = DEPTH_TOLERANCE * float(np.linalg.norm(np.ptp(np.asarray(vertices, np.float64), axis=0)))
        tol = max(tol, 1e-3 * float(np.ptp(depth)))
        vis = self._visible(view, box, px, depth, tol)
        self.vertex_quality = np.where(vis, np.clip(cos, 0.0, 1.0), 0.0).astype(np.float32)
        return self.vertex_quality, view, box, depth, cos, tol

    def observe(self, vertices: np.ndarray, px: np.ndarray, triangles: np.ndarray, uv: np.ndarray,
                P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the frame shows of the atlas: (texel pixels (S, S, 2) float32, NaN where no
        triangle covers the texel; quality (S, S) float32 in [0, 1]). Arguments as :meth:`see`,
        plus ``uv`` (V, 2) texture coordinates in [0, 1]. :meth:`draw_uv` (GL, the context's
        thread) then :meth:`finish` (CPU only: another thread may run it)."""
        return self.finish(*self.draw_uv(vertices, px, triangles, uv, P))

    def draw_uv(self, vertices, px, triangles, uv, P) -> tuple:
        """The GL part of :meth:`observe` (sets :attr:`vertex_quality` too): what :meth:`finish` takes."""
        S = self.size
        px = np.asarray(px, np.float64)
        _, view, box, depth, cos, tol = self.see(vertices, px, triangles, P)
        data = np.column_stack([np.asarray(uv, np.float32), px, depth, cos]).astype(np.float32)
        ctx = self.ctx
        vbo = ctx.buffer(data.tobytes())
        ibo = ctx.buffer(np.ascontiguousarray(triangles, np.uint32).tobytes())
        vao = ctx.vertex_array(self.uv_prog, [(vbo, "2f 2f 1f 1f", "in_uv", "in_px", "in_depth", "in_cos")],
                               index_buffer=ibo)
        self.fbo_uv.use()
        ctx.viewport = (0, 0, S, S)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND | moderngl.DEPTH_TEST)
        self.fbo_uv.clear(np.nan, np.nan, 0.0, -2.0, viewport=(0, 0, S, S))
        vao.render(moderngl.TRIANGLES)
        # read back the layout's bounding box only
        lo = np.clip(np.floor(np.min(uv, axis=0) * S).astype(int) - 1, 0, S - 1)
        hi = np.clip(np.ceil(np.max(uv, axis=0) * S).astype(int) + 1, lo + 1, S)
        obs = np.full((S, S, 4), np.nan, np.float32)
        obs[..., 3] = -2.0
        w, h = int(hi[0] - lo[0]), int(hi[1] - lo[1])
        obs[lo[1]:hi[1], lo[0]:hi[0]] = np.frombuffer(
            self.fbo_uv.read(viewport=(int(lo[0]), int(lo[1]), w, h), components=4, dtype="f4", alignment=1),
            np.float32).reshape(h, w, 4)
        for obj in (vao, vbo, ibo):
            obj.release()
        return obs, view, box, px, np.asarray(triangles, np.int64), tol

    def finish(self, obs, view, box, px, triangles, tol) -> tuple[np.ndarray, np.ndarray]:
        """The CPU part of :meth:`observe`: texel pixels and quality from :meth:`draw_uv`'s output."""
        S = self.size
        texel_px = obs[..., 0:2]
        covered = obs[..., 3] > -1.5
        texel_px[~covered] = np.nan
        quality = np.zeros((S, S), np.float32)
        if view is None or not covered.any():
            return texel_px, quality
        # frame pixels per texel (linear): the area of the texel's image, from differences (over
        # the covered texels' bounding box only)
        ys, xs = np.nonzero(covered.any(axis=1))[0], np.nonzero(covered.any(axis=0))[0]
        win = (slice(max(ys[0] - 1, 0), ys[-1] + 2), slice(max(xs[0] - 1, 0), xs[-1] + 2))
        gx = np.gradient(texel_px[win], axis=1)
        gy = np.gradient(texel_px[win], axis=0)
        size = np.zeros((S, S), np.float32)
        size[win] = np.sqrt(np.nan_to_num(np.abs(gx[..., 0] * gy[..., 1] - gx[..., 1] * gy[..., 0]), nan=0.0))
        idx = np.flatnonzero(covered)
        flat_px = texel_px.reshape(-1, 2)[idx].astype(np.float64)
        vis = self._visible(view, box, flat_px, obs[..., 2].reshape(-1)[idx], tol)
        vis &= ~self._near_edge(box, px, triangles, flat_px)
        q = np.clip(obs[..., 3].reshape(-1)[idx], 0.0, 1.0) * np.minimum(size.reshape(-1)[idx], 1.0)
        quality.reshape(-1)[idx] = np.where(vis, q, 0.0)
        return texel_px, quality

    def release(self) -> None:
        """Free the GL objects."""
        for name in ("fbo_view", "fbo_uv", "_view_color", "_view_depth", "_uv_color", "view_prog", "uv_prog"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
