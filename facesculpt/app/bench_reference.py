"""The fixed reference workload of `facesculpt bench`: what this machine does in a known amount of
work, measured in the same run as the figures, so that each figure can be given as a ratio to it
and compared across machines (a figure measured on a faster machine is smaller, and so is the
reference).

The workload is the renderer's kind of work, fixed in size and content (seeded, nothing read from
disk): on the CPU, OpenCV and numpy on a 480x856 frame (a Gaussian blur, a bicubic remap of a
256x256 block, a distance transform of a 256x256 disk, a 128x128 matrix product); on OpenGL (the
renderer's headless context: llvmpipe on a machine without a GPU), a 64x64 grid mesh (8192
triangles) drawn into a 256x256 two-float target with a depth test and read back. Each part is
timed ``repeats`` times and its median taken; the reference is the sum of the medians (ms).
"""

from __future__ import annotations

import time

import numpy as np

FRAME_SIZE = (856, 480)   # width, height of the CPU part's frame (px)
BLOCK = 256               # side of the remapped block, the disk's image and the GL target (px)
GRID = 64                 # cells a side of the drawn mesh: 2 * GRID**2 triangles
REPEATS = 31

_VS = """
#version 330
in vec2 in_pos;
in float in_depth;
in vec2 in_value;
out vec2 v_value;
void main() {
    gl_Position = vec4(in_pos, in_depth, 1.0);
    v_value = in_value;
}
"""
_FS = """
#version 330
in vec2 v_value;
out vec2 f_value;
void main() {
    f_value = v_value;
}
"""


def _cpu_inputs() -> dict:
    """The CPU part's fixed inputs: a smooth noise frame (H, W, 3) uint8, remap maps (BLOCK, BLOCK)
    float32 px, a disk mask (BLOCK, BLOCK) uint8 and two (128, 128) float64 matrices."""
    import cv2

    rng = np.random.default_rng(20261128)
    w, h = FRAME_SIZE
    frame = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), (5, 5), 1.0)
    yy, xx = np.mgrid[0:BLOCK, 0:BLOCK].astype(np.float32)
    map_x = xx + 100.0 + 3.0 * np.sin(yy / 17.0)
    map_y = yy + 100.0 + 3.0 * np.cos(xx / 13.0)
    disk = (((xx - BLOCK / 2) ** 2 + (yy - BLOCK / 2) ** 2) < (0.4 * BLOCK) ** 2).astype(np.uint8)
    return {"frame": frame, "map_x": map_x, "map_y": map_y, "disk": disk,
            "a": rng.standard_normal((128, 128)), "b": rng.standard_normal((128, 128))}


def _cpu_once(inputs: dict) -> None:
    import cv2

    cv2.GaussianBlur(inputs["frame"], (5, 5), 1.5)
    cv2.remap(inputs["frame"], inputs["map_x"], inputs["map_y"], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    cv2.distanceTransform(inputs["disk"], cv2.DIST_L2, 5)
    inputs["a"] @ inputs["b"]


def _grid_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The drawn mesh: ((GRID + 1)**2, 5) float32 vertices (x, y in [-0.9, 0.9], depth, two
    values) and (2 * GRID**2, 3) uint32 triangles."""
    t = np.linspace(-0.9, 0.9, GRID + 1, dtype=np.float32)
    x, y = np.meshgrid(t, t)
    depth = 0.5 * np.sin(3.0 * x) * np.cos(2.0 * y)
    vertices = np.stack([x, y, depth, x * 10.0, y * 10.0], axis=-1).reshape(-1, 5).astype(np.float32)
    i, j = np.meshgrid(np.arange(GRID), np.arange(GRID))
    a = (j * (GRID + 1) + i).ravel()
    quads = np.stack([a, a + 1, a + GRID + 1, a + 1, a + GRID + 2, a + GRID + 1], axis=1)
    return vertices, quads.reshape(-1, 3).astype(np.uint32)


class _GLPart:
    """The OpenGL part: a context of its own, the mesh in buffers, a BLOCK x BLOCK target."""

    def __init__(self):
        import moderngl

        from facesculpt.nodes.renderer.gl_context import create_headless_context

        self.moderngl = moderngl
        self.ctx = create_headless_context()
        vertices, triangles = _grid_mesh()
        self.prog = self.ctx.program(vertex_shader=_VS, fragment_shader=_FS)
        self.vbo = self.ctx.buffer(vertices.tobytes())
        self.ibo = self.ctx.buffer(triangles.tobytes())
        self.vao = self.ctx.vertex_array(self.prog, [(self.vbo, "2f 1f 2f", "in_pos", "in_depth", "in_value")],
                                         index_buffer=self.ibo)
        self.colour = self.ctx.renderbuffer((BLOCK, BLOCK), 2, dtype="f4")
        self.depth = self.ctx.depth_renderbuffer((BLOCK, BLOCK))
        self.fbo = self.ctx.framebuffer([self.colour], self.depth)
        self.n = 3 * len(triangles)

    def once(self) -> None:
        ctx = self.ctx
        self.fbo.use()
        ctx.viewport = (0, 0, BLOCK, BLOCK)
        ctx.enable(self.moderngl.DEPTH_TEST)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.vao.render(self.moderngl.TRIANGLES, vertices=self.n)
        self.fbo.read(components=2, dtype="f4")

    def release(self) -> None:
        for obj in (self.vao, self.vbo, self.ibo, self.fbo, self.colour, self.depth, self.prog, self.ctx):
            obj.release()


def _median_ms(fn, repeats: int) -> float:
    fn()   # warm: first calls compile shaders and fill caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def reference_workload(repeats: int = REPEATS) -> dict:
    """Time the reference workload on this machine, now: {"cpu_ms", "gl_ms", "total_ms"}, the
    medians over ``repeats`` runs of each part (ms) and their sum; "gl_ms" is None (and the total
    the CPU part's) where no OpenGL context can be made. ValueError for ``repeats`` < 1."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    inputs = _cpu_inputs()
    cpu = _median_ms(lambda: _cpu_once(inputs), repeats)
    try:
        gl = _GLPart()
    except RuntimeError:
        gl_ms = None
    else:
        try:
            gl_ms = _median_ms(gl.once, repeats)
        finally:
            gl.release()
    total = cpu + (gl_ms or 0.0)
    return {"cpu_ms": round(cpu, 3), "gl_ms": None if gl_ms is None else round(gl_ms, 3), "total_ms": round(total, 3)}


def as_ratio(ms: float | None, reference_ms: float | None) -> float | None:
    """``ms`` over the reference's ms (a figure in units of the reference workload), None when
    either is missing or the reference is not positive."""
    if ms is None or not reference_ms or reference_ms <= 0:
        return None
    return round(float(ms) / float(reference_ms), 3)


def add_ratios(result: dict, start: dict, end: dict) -> float | None:
    """Put the reference measured at the ``start`` and the ``end`` of a bench run (each
    :func:`reference_workload`'s) into the bench's ``result`` as "reference" (their mean total, ms,
    is the reference), and beside each model's ms figures their ratios to it: "stages_ratio" (each
    of "stages_ms"), and "frame_period_ratio" (1000 / pipelined fps) and "latency_ratio" (p50,
    p99) where the graph was measured. Returns the reference (ms; None without one)."""
    totals = [r["total_ms"] for r in (start, end) if r and r.get("total_ms")]
    ref = round(float(np.mean(totals)), 3) if totals else None
    result["reference"] = {"total_ms": ref, "start": start, "end": end,
                           "workload": "numpy + OpenCV on a 856x480 frame, and 8192 triangles drawn and read back "
                                       "through the renderer's OpenGL (facesculpt/app/bench_reference.py)"}
    for entry in result["models"].values():
        entry["stages_ratio"] = {k: as_ratio(v, ref) for k, v in entry.get("stages_ms", {}).items()}
        fps = entry.get("pipelined_fps")
        if fps:
            entry["frame_period_ratio"] = as_ratio(1000.0 / fps, ref)
        latency = entry.get("latency_ms") or {}
        if latency:
            entry["latency_ratio"] = {k: as_ratio(latency.get(k), ref) for k in ("p50", "p99")}
    return ref
