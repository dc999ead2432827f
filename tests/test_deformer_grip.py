"""A handle may grip a patch of skin (``EditStack(grip=...)``, an option; by default a handle is
the single vertex of the paper's ARAP): with a grip the surface around a pulled point follows it
instead of leaving a spike, pressing on an edited surface moves nothing either way, and pins and
explicit ROIs still bound what moves."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.nodes.deformer import DeformerError, EditStack
from facesculpt.nodes.deformer.anchors import distances_from


@pytest.fixture(scope="module")
def model(data_dir):
    from facesculpt.nodes.fitter import load_model

    return load_model("sfm")


def stack_for(model, **kw):
    return EditStack(model.mean, model.triangles, model.landmark_names, model.landmark_vertices, **kw)


def pull_nose(stack, offset=(0.0, -3.0, 8.0)):
    v = stack.landmark_vertex("nose_tip")
    stack.begin([v], roi_radius=30.0)
    stack.set_offset(v, offset)
    return v, stack.solve(iterations=60)


def test_the_skin_around_a_pulled_point_follows_it_instead_of_a_spike(model):
    spike, grip = stack_for(model, grip=0.0), stack_for(model, grip=0.2)
    v, d_spike = pull_nose(spike)
    _, d_grip = pull_nose(grip)
    r = distances_from(grip.rest, [v], "geodesic", triangles=grip.triangles)
    near = (r > 0) & (r < 6.0)  # the pulled point's neighbourhood, within the grip
    ring = (r > 9.0) & (r < 15.0)  # beyond the grip, inside the ROI
    moved = lambda d, m: float(np.linalg.norm(d[m], axis=1).mean())  # noqa: E731
    handle = float(np.linalg.norm(d_grip[v]))
    assert np.allclose(d_grip[v], d_spike[v])  # the handle lands where asked either way
    assert moved(d_grip, near) > 0.95 * handle
    assert moved(d_spike, near) < 0.75 * handle  # the single vertex drags a spike
    assert moved(d_grip, ring) > moved(d_spike, ring) + 1.0
    outside = r > 30.0 * 1.2
    assert np.all(d_grip[outside] == 0)


def test_by_default_a_handle_is_the_single_vertex_of_the_papers_arap(model):
    s = stack_for(model)
    v, d = pull_nose(s)
    static, constrained, _, _ = s.constraints()
    assert s.grip == 0.0 and list(constrained) == [v]  # the handle alone is moved: nothing grips
    assert np.allclose(d[v], (0.0, -3.0, 8.0))


@pytest.mark.parametrize("grip", [0.0, 0.2])
def test_pressing_on_an_edited_surface_moves_nothing(model, grip):
    s = stack_for(model, grip=grip)
    v, before = pull_nose(s)
    r = distances_from(s.rest, [v], "geodesic", triangles=s.triangles)
    # press on the pulled surface, 10 mm from the tip, with an ROI inside the first one: its grip
    # vertices were moved by the first edit, each by its own amount, and must stay where they are
    beside = int(np.argmin(np.abs(r - 10.0)))
    s.begin([beside], roi_radius=15.0)
    assert np.abs(s.solve(iterations=60) - before).max() < 0.05
    s.begin([v], roi_radius=30.0)  # and on the pulled point itself
    assert np.abs(s.solve(iterations=60) - before).max() < 0.05


def test_pins_and_explicit_rois_bound_the_grip(model):
    s = stack_for(model, grip=0.2)
    v = s.landmark_vertex("nose_tip")
    r = distances_from(s.rest, [v], "geodesic", triangles=s.triangles)
    pin = int(np.flatnonzero((r > 2.0) & (r < 5.0))[0])
    s.toggle_static(pin)
    roi = np.flatnonzero(r < 4.0)
    s.begin([v], roi=roi)
    s.set_offset(v, (0.0, 0.0, 5.0))
    d = s.solve(iterations=30)
    assert np.all(d[pin] == 0)
    assert np.all(d[np.setdiff1d(np.arange(s.n), roi)] == 0)  # nothing outside the explicit ROI moves
    static, constrained, free, _ = s.constraints()
    assert pin in static and pin not in constrained and v in constrained


@pytest.mark.parametrize("grip", [-0.1, 0.6, float("nan")])
def test_grip_outside_its_range_is_one_sentence(model, grip):
    with pytest.raises(DeformerError, match="grip must be a share of the ROI radius"):
        stack_for(model, grip=grip)
