"""Picking and dragging on a posed, rendered Surrey Face Model: the vertex under the cursor is
checked against a triangle-id buffer rendered with OpenGL (EGL), at yaw 0 and 40 degrees."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesculpt.geometry import axes_velocity, merge_deformation, pixel_ray, project
from facesculpt.nodes.deformer import ArapDeformer
from facesculpt.nodes.deformer.anchors import roi_within_radius
from facesculpt.nodes.deformer.dragging import camera_to_model_vector, depth_delta, drag_delta
from facesculpt.nodes.deformer.picking import pick_vertex

W, H = 640, 480
K = np.array([[900.0, 0.0, 322.0], [0.0, 900.0, 236.0], [0.0, 0.0, 1.0]])
NEAR, FAR = 100.0, 2000.0


@pytest.fixture(scope="module")
def sfm(data_dir):
    from facesculpt.nodes.fitter import load_model

    m = load_model("sfm")
    return m.mean.astype(np.float64), m.triangles.astype(np.int64), m.landmark_index()


@pytest.fixture(scope="module")
def gl():
    moderngl = pytest.importorskip("moderngl")
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # no EGL on this machine
        pytest.skip(f"no OpenGL context: {exc}")
    prog = ctx.program(
        vertex_shader="""
            #version 330
            uniform vec4 intr;   // fx, fy, cx, cy
            uniform vec2 size;   // W, H
            uniform vec2 nf;     // near, far
            in vec3 pos;         // camera space, OpenCV axes
            void main() {
                float u = intr.x * pos.x / pos.z + intr.z;
                float v = intr.y * pos.y / pos.z + intr.w;
                float a = (nf.y + nf.x) / (nf.y - nf.x);
                float b = -2.0 * nf.y * nf.x / (nf.y - nf.x);
                gl_Position = vec4((2.0 * u / size.x - 1.0) * pos.z, (1.0 - 2.0 * v / size.y) * pos.z,
                                   a * pos.z + b, pos.z);
            }""",
        fragment_shader="""
            #version 330
            out int id;
            void main() { id = gl_PrimitiveID + 1; }""",
    )
    prog["intr"].value = (K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    prog["size"].value = (W, H)
    prog["nf"].value = (NEAR, FAR)
    yield ctx, prog
    ctx.release()


def render_triangle_ids(gl, vertices_cam, triangles):
    """(H, W) int: 1 + index of the triangle seen at each pixel, 0 for background."""
    ctx, prog = gl
    tex = ctx.texture((W, H), 1, dtype="i4")
    depth = ctx.depth_renderbuffer((W, H))
    fbo = ctx.framebuffer(color_attachments=[tex], depth_attachment=depth)
    vbo = ctx.buffer(np.ascontiguousarray(vertices_cam[triangles.ravel()], dtype="f4").tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "3f", "pos")])
    fbo.use()
    ctx.enable(ctx.DEPTH_TEST)
    fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    vao.render()
    ids = np.frombuffer(fbo.read(components=1, dtype="i4"), dtype=np.int32).reshape(H, W)[::-1]
    for obj in (vao, vbo, fbo, depth, tex):
        obj.release()
    return ids


def pose(yaw_deg):
    """Model (y up, z toward the viewer) -> OpenCV camera at 600 mm, turned by ``yaw``."""
    R = np.diag([1.0, -1.0, -1.0]) @ Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    return R, 1.05, np.array([4.0, -10.0, 600.0])


def one_ring_triangles(triangles):
    """For each triangle, the set of vertices of it and of every triangle sharing a vertex."""
    by_vertex = [[] for _ in range(triangles.max() + 1)]
    for k, tri in enumerate(triangles):
        for v in tri:
            by_vertex[v].append(k)
    return lambda k: set(triangles[sum((by_vertex[v] for v in triangles[k]), [])].ravel())


@pytest.mark.parametrize("yaw", [0.0, 40.0])
@pytest.mark.parametrize("deformed", [False, True])
def test_pick_returns_vertex_under_cursor(sfm, gl, yaw, deformed):
    V, F, lm = sfm
    R, s, t = pose(yaw)
    fitted = (s * V @ R.T + t).astype(np.float32)
    displacement = np.zeros_like(V)
    if deformed:  # the current mesh is the deformed fitted mesh (a pulled nose)
        d = ArapDeformer(V, F)
        h = [lm["nose_tip"]]
        d.set_anchors(handles=h, roi=np.setdiff1d(roi_within_radius(V, h, 45.0, triangles=F), h))
        displacement = d.solve(V[h] + [0.0, -5.0, 20.0]) - V
    mesh = merge_deformation(fitted, R, s, displacement).astype(np.float64)
    ids = render_triangle_ids(gl, mesh, F)
    ys, xs = np.nonzero(ids)
    assert ys.size > 20000  # the face covers the image centre
    rng = np.random.default_rng(int(yaw) + 7 * deformed)
    sample = rng.choice(ys.size, 150, replace=False)
    near = one_ring_triangles(F)
    exact = 0
    for k in sample:
        x, y = xs[k] + 0.5, ys[k] + 0.5
        tri = ids[ys[k], xs[k]] - 1
        hit = pick_vertex(x, y, K, mesh, F)
        assert hit is not None, (x, y)
        exact += hit.triangle == tri or hit.vertex in F[tri]
        assert hit.vertex in near(tri)  # within one triangle of the rendered one
    assert exact >= 0.9 * len(sample)
    # the nose tip's own pixel picks a vertex next to the nose tip
    u = project(mesh[[lm["nose_tip"]]], K)[0]
    hit = pick_vertex(u[0], u[1], K, mesh, F)
    assert hit is not None and np.linalg.norm(mesh[hit.vertex] - mesh[lm["nose_tip"]]) < 6.0


def test_miss_selects_nothing(sfm):
    V, F, _ = sfm
    R, s, t = pose(0.0)
    mesh = s * V @ R.T + t
    assert pick_vertex(5.0, 5.0, K, mesh, F) is None  # image corner: background
    assert pick_vertex(float("nan"), 100.0, K, mesh, F) is None


def test_orthographic_ray_hits_front_surface(sfm):
    """Scaled orthographic as the fitter does it: camera space in pixel scale, pixel = (x, y)."""
    V, F, lm = sfm
    R, _, _ = pose(20.0)
    s, t = 2.2, np.array([320.0, 240.0, 0.0])  # px per mm
    mesh = s * V @ R.T + t
    nose = lm["nose_tip"]
    u = project(mesh[[nose]], None, "orthographic")[0]
    assert np.allclose(u, mesh[nose, :2])
    hit = pick_vertex(u[0], u[1], None, mesh, F, "orthographic")
    assert hit is not None and np.linalg.norm(mesh[hit.vertex] - mesh[nose]) < 6.0 * s
    assert abs(hit.point[2] - mesh[nose, 2]) < 3.0 * s  # the front surface, not the back of the head
    # a drag of (10, -4) px moves the handle 10/s, -4/s mm in the image plane
    delta = drag_delta(mesh[nose], u, u + [10.0, -4.0], None, R, s, "orthographic")
    moved = s * R @ (V[nose] + delta) + t
    assert np.allclose(moved[:2], u + [10.0, -4.0]) and np.isclose(moved[2], mesh[nose, 2])


@pytest.mark.parametrize("yaw", [0.0, 40.0])
def test_drag_moves_handle_under_cursor_at_its_depth(sfm, yaw):
    V, F, lm = sfm
    R, s, t = pose(yaw)
    v = lm["nose_tip"]
    handle_cam = s * R @ V[v] + t
    start = project(handle_cam[None], K)[0]
    end = start + np.array([30.0, -12.0])
    delta = drag_delta(handle_cam, start, end, K, R, s)
    moved_cam = s * R @ (V[v] + delta) + t
    assert np.allclose(project(moved_cam[None], K)[0], end, atol=1e-6)  # under the cursor
    assert abs(moved_cam[2] - handle_cam[2]) < 1e-9  # at the handle's depth
    # depth: +5 mm moves 5 model-mm along the view ray toward the camera
    dz = depth_delta(handle_cam, 5.0, R)
    assert np.isclose(np.linalg.norm(dz), 5.0)
    closer = s * R @ (V[v] + dz) + t
    assert np.linalg.norm(closer) < np.linalg.norm(handle_cam)
    assert np.allclose(project(closer[None], K)[0], start, atol=1e-6)  # still under the same pixel
    # a camera-plane vector goes back through the inverse pose
    assert np.allclose(s * R @ camera_to_model_vector([1.0, 2.0, 3.0], R, s), [1.0, 2.0, 3.0])


def test_pixel_ray_and_axes():
    o, d = pixel_ray(K[0, 2], K[1, 2], K)
    assert np.allclose(o, 0) and np.allclose(d, [0, 0, 1])
    v = axes_velocity([0.05, -1.0, 0.5], speed_mm_s=20.0, deadzone=0.1)
    assert v[0] == 0.0  # inside the dead zone
    assert np.isclose(v[1], 20.0)  # stick forward -> model +y
    assert 0 < v[2] < 20.0
    assert np.all(axes_velocity([np.nan], 20.0) == 0)
