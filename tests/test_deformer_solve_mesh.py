"""A coarse model mesh is solved on its refinement (``facesculpt/nodes/deformer/solve_mesh.py``): the face
mesh's pulled chin moves the skin around the handle with it on the surface the renderer draws,
the Surrey model is solved on itself, and an edit still moves nothing outside its ROI."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.geometry.close_holes import close_holes
from facesculpt.geometry.subdivision import loop_subdivision, midpoint_subdivision
from facesculpt.nodes.deformer import DeformerError, EditStack
from facesculpt.nodes.deformer.preset_format import find_preset, read_preset_file
from facesculpt.nodes.deformer.solve_mesh import solve_levels, solve_mesh
from facesculpt.nodes.fitter import load_model


def _stack(model, **kw) -> EditStack:
    return EditStack(model.mean, model.triangles, model.landmark_names, model.landmark_vertices, **kw)


def test_midpoint_subdivision_has_loops_vertices_and_triangles_on_the_flat_surface():
    ys, xs = np.mgrid[0:4, 0:5].astype(np.float64)
    rest = np.column_stack([xs.ravel() * 10, ys.ravel() * 10, np.zeros(xs.size)])
    idx = np.arange(20).reshape(4, 5)
    tri = np.concatenate([np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel()]),
                          np.column_stack([idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()])])
    M, fine = midpoint_subdivision(tri, 20, 2)
    S, loop_fine = loop_subdivision(tri, 20, 2)
    assert np.array_equal(fine, loop_fine) and M.shape == S.shape
    np.testing.assert_allclose(np.asarray(M.sum(axis=1)).ravel(), 1.0)
    points = M @ rest
    np.testing.assert_array_equal(points[:20], rest)            # the old vertices stay where they are
    assert np.all(points[:, 2] == 0)                              # on the flat surface
    # every fine triangle has a quarter of a quarter of its coarse triangle's area (flat mesh)
    area = 0.5 * np.abs(np.cross(points[fine[:, 1]] - points[fine[:, 0]], points[fine[:, 2]] - points[fine[:, 0]])[:, 2])
    np.testing.assert_allclose(area, 50.0 / 16)
    with pytest.raises(ValueError):
        midpoint_subdivision(tri, 20, -1)


def test_the_face_mesh_is_solved_on_a_refinement_and_the_surrey_model_on_itself():
    face, sfm = load_model("facemesh"), load_model("sfm")
    fm = solve_mesh(face.mean, face.triangles)
    assert fm.levels == 1 and len(fm.rest) >= 1500
    np.testing.assert_allclose(fm.rest[: fm.n], face.mean)      # model vertex v is solve vertex v
    assert solve_mesh(sfm.mean, sfm.triangles).levels == 0
    assert solve_mesh(face.mean, face.triangles, 0).levels == 0
    assert solve_levels(face.num_vertices, len(face.triangles), 3000) == 2
    assert solve_levels(sfm.num_vertices, len(sfm.triangles), 3000) == 0
    # a displacement the Loop surface can show is recovered exactly from that surface
    rng = np.random.default_rng(1)
    D = rng.normal(size=(fm.n, 3))
    np.testing.assert_allclose(fm.to_model(fm.loop @ D), D, atol=1e-8)
    assert _stack(sfm).deformer.n == sfm.num_vertices   # the Surrey model is its own solve mesh


def _pull_along_handle(model, stack: EditStack, radius_mm: float = 5.0) -> float:
    """How far the drawn surface (two Loop levels of the closed mesh, as the renderer draws it)
    within ``radius_mm`` of the chin handle moved along the handle's offset, as a share of it."""
    (handle, offset), = stack.edits[0].offsets.items()
    S, _ = loop_subdivision(close_holes(model.triangles), model.num_vertices, 2)
    S = S.astype(np.float64)
    rest, moved = S @ np.asarray(model.mean, np.float64), S @ stack.settle()
    near = np.linalg.norm(rest - model.mean[handle], axis=1) < radius_mm
    u = offset / np.linalg.norm(offset)
    return float((moved[near] @ u).mean() / np.linalg.norm(offset))


def test_a_pulled_chin_moves_the_skin_around_the_handle_on_the_face_mesh():
    """On the 468-point mesh the chin's grip (an option: ``grip=0.2``) holds the handle vertex
    alone: solved on the mesh itself, the skin within 5 mm of the handle moves well short of the
    pull; solved on the refinement, it moves with it."""
    face = load_model("facemesh")
    doc = {"format": "facesculpt-deformer-preset", "version": 1, "units": "mm", "static": [],   # the chin vertex alone
           "edits": [{"handles": [{"landmark": "chin", "offset": [0.0, -10.0, 4.0]}],
                      "roi": {"radius": 45.0, "metric": "geodesic"}}]}
    coarse, refined = _stack(face, min_solve_vertices=0, grip=0.2), _stack(face, grip=0.2)
    for s in (coarse, refined):
        s.apply_preset(doc)
    short, full = _pull_along_handle(face, coarse), _pull_along_handle(face, refined)
    assert short < 0.9
    assert 0.95 < full < 1.1


def test_a_refined_solve_moves_nothing_outside_the_roi():
    face = load_model("facemesh")
    stack = _stack(face)
    chin = stack.landmark_vertex("chin")
    near = np.flatnonzero(np.linalg.norm(face.mean - face.mean[chin], axis=1) < 25.0)
    stack.begin([chin], roi=near)
    stack.set_offset(chin, [0.0, -6.0, 2.0])
    D = stack.settle()
    outside = np.setdiff1d(np.arange(face.num_vertices), near)
    assert np.abs(D[outside]).max() == 0.0          # exactly still: the renderer redraws no more
    assert np.linalg.norm(D[chin]) > 5.0
    # a preset by radius too: far from its handle nothing moves
    stack.apply_preset(read_preset_file(find_preset("nose_longer")))
    D = stack.settle()
    far = np.linalg.norm(face.mean - face.mean[stack.landmark_vertex("nose_tip")], axis=1) > 80.0
    assert far.any() and np.abs(D[far]).max() == 0.0


def test_min_solve_vertices_is_checked():
    face = load_model("facemesh")
    for bad in (-1, 10**6, 2.5, True):
        with pytest.raises(DeformerError, match="min_solve_vertices"):
            _stack(face, min_solve_vertices=bad)
