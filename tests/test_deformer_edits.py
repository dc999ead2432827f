"""Edit layers (accumulate, undo, reset), JSON presets across identities and topologies, ROI
selection, and the Eq. 5 merge."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesculpt.geometry import merge_deformation
from facesculpt.nodes.deformer import DeformerError, EditStack
from facesculpt.nodes.deformer.anchors import distances_from, roi_within_radius


@pytest.fixture(scope="module")
def model(data_dir):
    from facesculpt.nodes.fitter import load_model

    return load_model("sfm")


def stack_for(model, vertices=None, triangles=None, **kw):
    V = model.mean if vertices is None else vertices
    F = model.triangles if triangles is None else triangles
    return EditStack(V, F, model.landmark_names, model.landmark_vertices, **kw)


# the paper's Fig. 6e sequence: nose stretched, chin pointed, both cheeks
FIG6E = [
    {"nose_tip": [0.0, -3.0, 12.0]},
    {"chin": [0.0, -10.0, 6.0]},
    {"left_cheek": [-6.0, 0.0, 0.0], "right_cheek": [6.0, 0.0, 0.0]},
]


def make_edits(stack, edits=FIG6E):
    for edit in edits:
        verts = [stack.landmark_vertex(k) for k in edit]
        stack.begin(verts)
        for v, off in zip(verts, edit.values()):
            stack.set_offset(v, off)
        stack.solve()


def test_edits_accumulate_undo_and_reset(model):
    s = stack_for(model)
    make_edits(s)
    d_all = s.displacement.copy()
    for edit in FIG6E:  # every edit's handles are still where it put them
        for name, off in edit.items():
            assert np.allclose(d_all[s.landmark_vertex(name)], off, atol=1e-9)
    static, handles, roi, _ = s.anchors()
    assert len(handles) == 4 and len(roi) > 500
    outside = np.setdiff1d(np.arange(s.n), np.concatenate([roi, handles]))
    assert np.all(d_all[outside] == 0)  # nothing outside every ROI moves

    # undo drops the cheeks: the result is that of nose + chin alone
    assert s.undo()
    d_undo = s.solve(iterations=60)
    fresh = stack_for(model)
    make_edits(fresh, FIG6E[:2])
    assert np.allclose(d_undo[s.landmark_vertex("left_cheek")], fresh.solve(iterations=60)[s.landmark_vertex("left_cheek")], atol=0.05)
    assert not np.allclose(d_undo, d_all)
    s.clear()
    assert np.all(s.solve() == 0)
    assert not s.undo()


def test_later_edit_of_same_handle_wins_and_undo_restores(model):
    s = stack_for(model)
    v = s.landmark_vertex("nose_tip")
    s.begin([v])
    s.set_offset(v, [0.0, 0.0, 5.0])
    s.solve()
    s.begin([v])  # press again on the same vertex: starts from where it is
    assert np.allclose(s.handle_position(v), s.rest[v] + [0, 0, 5])
    s.move_handle(v, [0.0, 2.0, 0.0])
    assert np.allclose(s.solve()[v], [0, 2, 5])
    s.undo()
    assert np.allclose(s.solve()[v], [0, 0, 5])


def test_preset_from_one_identity_moves_same_landmarks_on_another(model, tmp_path):
    rng = np.random.default_rng(11)
    person_a = model.instance(rng.normal(size=model.num_shape) * 0.8)
    person_b = model.instance(rng.normal(size=model.num_shape) * 0.8)
    assert np.abs(person_a - person_b).max() > 5.0  # really two different faces
    a = stack_for(model, person_a)
    make_edits(a)
    path = tmp_path / "fig6e.json"
    a.save_preset(path)
    doc = json.loads(path.read_text())
    named = [h["landmark"] for e in doc["edits"] for h in e["handles"]]
    assert named == ["nose_tip", "chin", "left_cheek", "right_cheek"]

    b = stack_for(model, person_b)
    b.load_preset(path)
    d_b = b.solve()
    for edit in FIG6E:
        for name, off in edit.items():
            assert np.allclose(d_b[b.landmark_vertex(name)], off, atol=1e-6)
    # the deformation spreads over each person's own surface: similar, not identical
    d_a = a.displacement
    moved = np.linalg.norm(d_a, axis=1) > 0.5
    assert np.corrcoef(d_a[moved].ravel(), d_b[moved].ravel())[0, 1] > 0.9
    assert np.abs(d_a - d_b).max() > 1e-3


def test_preset_on_other_topology_places_unnamed_handles_by_landmarks(model, tmp_path):
    s = stack_for(model)
    make_edits(s, FIG6E[:1])
    s.begin([5])  # vertex 5 is not a named landmark
    s.set_offset(5, [1.0, 0.0, 0.0])
    s.solve()
    doc = s.to_preset()
    handle = doc["edits"][1]["handles"][0]
    assert handle["vertex"] == 5 and np.allclose(handle["point"], model.mean[5], atol=1e-3)
    assert set(doc["landmarks"]) >= {"nose_tip", "left_eye_outer", "right_eye_outer"}
    assert not any(k.isdigit() for k in doc["landmarks"])  # iBUG numbers are no names other models share
    # same vertices, triangles listed in another order: a different topology signature; the
    # landmarks are where they were, so the handle lands on vertex 5 again
    other = stack_for(model, triangles=model.triangles[::-1].copy())
    other.apply_preset(doc)
    assert sorted(other.edits[1].offsets) == [5]
    # a preset written before handles carried their position (vertex only) still needs the same topology
    old = json.loads(json.dumps(doc))
    del old["edits"][1]["handles"][0]["point"]
    with pytest.raises(DeformerError, match="different mesh topology"):
        other.apply_preset(old)
    assert sorted(other.edits[1].offsets) == [5]  # nothing half-applied
    s.apply_preset(old)  # on its own topology the vertex index is exact
    assert sorted(s.edits[1].offsets) == [5]
    old["edits"] = old["edits"][:1]
    other.apply_preset(old)
    # (turned by the rotation between the two meshes' landmarks: the identity, to rounding)
    assert np.allclose(other.solve()[other.landmark_vertex("nose_tip")], FIG6E[0]["nose_tip"], atol=1e-5)


def test_preset_from_a_model_with_other_axes_is_turned_into_this_models(model):
    """A preset made on a mesh whose model space is this one pitched by 8 degrees (another model:
    the face mesh's "up" follows its forehead-chin line) moves this mesh's handle the same way on
    the face: its offset is turned by the rotation the landmarks both name show, and keeps its
    length; without the landmarks (where the preset was made is unknown) it is taken as it is."""
    from facesculpt.nodes.deformer.landmark_warp import frame_rotation, landmark_positions

    turn = Rotation.from_euler("x", 8.0, degrees=True).as_matrix()
    pitched = stack_for(model, vertices=(model.mean.reshape(-1, 3) @ turn.T).astype(np.float32),
                        triangles=model.triangles[::-1].copy())   # another topology signature
    make_edits(pitched, FIG6E[:1])
    doc = pitched.to_preset()
    here = stack_for(model)
    here.apply_preset(doc)
    tip = here.landmark_vertex("nose_tip")
    got = here.edits[0].offsets[tip]
    assert np.allclose(got, turn.T @ FIG6E[0]["nose_tip"], atol=1e-6)
    assert not np.allclose(got, FIG6E[0]["nose_tip"], atol=0.5)
    # the rotation itself, and too few shared landmarks: none
    marks = landmark_positions(here.rest, here.landmarks)
    assert np.allclose(frame_rotation({k: turn @ p for k, p in marks.items()}, marks), turn.T, atol=1e-9)
    few = dict(list(marks.items())[:3])
    assert np.array_equal(frame_rotation(few, marks), np.eye(3))
    del doc["landmarks"], doc["topology"]
    here.apply_preset(doc)
    assert np.allclose(here.edits[0].offsets[tip], FIG6E[0]["nose_tip"])


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d["edits"][0]["handles"][0].update(landmark="third_ear", aliases=[]), "no landmark named"),
        (lambda d: d["edits"][0]["handles"][0].update(offset=[0, float("nan"), 0]), "finite"),
        (lambda d: d.update(format="something else"), "not a"),
        (lambda d: d["edits"][0].pop("handles"), "malformed"),
        (lambda d: d["edits"][0]["roi"].update(radius=-3), "radius"),
    ],
)
def test_bad_presets_raise_and_change_nothing(model, mutate, message):
    s = stack_for(model)
    make_edits(s, FIG6E[:2])
    before = s.to_preset()
    doc = json.loads(json.dumps(before))
    mutate(doc)
    with pytest.raises(DeformerError, match=message):
        s.apply_preset(doc)
    assert s.to_preset() == before


def test_unreadable_preset_file(model, tmp_path):
    s = stack_for(model)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DeformerError, match="cannot read"):
        s.load_preset(bad)
    with pytest.raises(DeformerError, match="cannot read"):
        s.load_preset(tmp_path / "missing.json")


def test_empty_roi_and_bad_handles_raise(model):
    s = stack_for(model, roi_radius=1e-3)  # a radius that reaches no neighbour
    s.begin([s.landmark_vertex("nose_tip")])
    with pytest.raises(DeformerError, match="empty"):
        s.solve()
    t = stack_for(model)
    with pytest.raises(DeformerError, match="out of range"):
        t.begin([t.n])
    with pytest.raises(DeformerError, match="press a handle first"):
        t.move_handle(0, [1, 0, 0])
    t.begin([0])
    with pytest.raises(DeformerError, match="finite"):
        t.move_handle(0, [np.nan, 0, 0])
    with pytest.raises(DeformerError, match="metric"):
        stack_for(model, roi_metric="manhattan")


def test_roi_radius_geodesic_and_euclidean(model):
    V, F = model.mean.astype(np.float64), model.triangles
    nose = model.landmark_index()["nose_tip"]
    geo = roi_within_radius(V, [nose], 40.0, "geodesic", triangles=F)
    euc = roi_within_radius(V, [nose], 40.0, "euclidean")
    assert nose in geo and nose in euc
    assert set(geo) <= set(euc)  # a path along the surface is never shorter than a straight line
    d = distances_from(V, [nose], "euclidean")
    assert np.all(d[euc] <= 40.0) and np.all(np.delete(d, euc) > 40.0)
    # the path length is within a few percent of the straight line for nearby vertices on a smooth patch
    g = distances_from(V, [nose], "geodesic", triangles=F)
    close = (d > 3) & (d < 10)
    assert np.median(g[close] / d[close]) < 1.15


def test_merge_turns_displacement_into_pose():
    rng = np.random.default_rng(0)
    model_pts = rng.normal(size=(50, 3)) * 40
    disp = rng.normal(size=(50, 3))
    R = Rotation.from_euler("xyz", [10, 40, -5], degrees=True).as_matrix()
    s, t = 1.3, np.array([1.0, 2.0, 500.0])
    fitted = (s * model_pts @ R.T + t).astype(np.float32)
    out = merge_deformation(fitted, R, s, disp)
    assert out.dtype == np.float32
    assert np.allclose(out, s * (model_pts + disp) @ R.T + t, atol=1e-3)
    w = np.linspace(0, 1, 50)
    half = merge_deformation(fitted, R, s, disp, weights=w)
    assert np.allclose(half, s * (model_pts + w[:, None] * disp) @ R.T + t, atol=1e-3)
    with pytest.raises(ValueError):
        merge_deformation(fitted, R, s, disp[:10])


def fit_video(model, data_dir, models_dir, name, frames=12):
    """Fit the SFM to the first frames of a shared video: (FitResult, person's neutral (V, 3))."""
    cv2 = pytest.importorskip("cv2")
    from facesculpt.geometry import to_ibug68
    from facesculpt.nodes.fitter import FitterConfig, make_fitter
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    detector = LandmarkDetector(models_dir)
    cap = cv2.VideoCapture(str(data_dir / "video" / f"{name}.mp4"))
    fitter = None
    result = None
    for _ in range(frames):
        ok, frame = cap.read()
        assert ok, f"cannot read {name}.mp4"
        if fitter is None:
            fitter = make_fitter(model, FitterConfig(), (frame.shape[1], frame.shape[0]))
        faces = detector.track(frame)
        assert faces, f"no face in {name}.mp4"
        result = fitter.fit(to_ibug68(faces[0].points))
    cap.release()
    return result, model.instance(result.alpha)


@pytest.mark.slow
def test_preset_from_one_video_applies_to_another(model, data_dir, models_dir, tmp_path):
    """Edits made on the person fitted in d0.mp4, saved, loaded on the person in d3.mp4: the same
    named landmarks move by the same model-space offsets, and in d3's frame they move on screen by
    that offset in d3's head pose; a click on d3's deformed face picks the moved nose."""
    from facesculpt.geometry import project
    from facesculpt.nodes.deformer.picking import pick_vertex

    fit_a, person_a = fit_video(model, data_dir, models_dir, "d0")
    fit_b, person_b = fit_video(model, data_dir, models_dir, "d3")
    assert np.abs(person_a - person_b).max() > 2.0  # two fitted identities
    a = stack_for(model, person_a)
    make_edits(a)
    a.save_preset(tmp_path / "video.json")
    b = stack_for(model, person_b)
    b.load_preset(tmp_path / "video.json")
    disp = b.solve()
    merged = merge_deformation(fit_b.vertices, fit_b.R, fit_b.scale, disp)
    for edit in FIG6E:
        for name, off in edit.items():
            v = b.landmark_vertex(name)
            assert np.allclose(disp[v], off, atol=1e-6)
            on_screen = merged[v, :2] - fit_b.vertices[v, :2]  # orthographic: camera x, y are pixels
            assert np.allclose(on_screen, (fit_b.scale * fit_b.R @ np.asarray(off))[:2], atol=1e-3)
    nose = b.landmark_vertex("nose_tip")
    u = project(merged[[nose]].astype(np.float64), None, fit_b.projection)[0]
    hit = pick_vertex(u[0], u[1], fit_b.K, merged, model.triangles, fit_b.projection)
    assert hit is not None and np.linalg.norm(person_b[hit.vertex] + disp[hit.vertex] - person_b[nose] - disp[nose]) < 6.0


def test_strength_scales_offsets_from_argument_and_preset_field(model):
    from facesculpt.nodes.deformer.preset_format import scale_preset

    s = stack_for(model)
    make_edits(s, FIG6E[:2])
    doc = s.to_preset()
    nose, chin = s.landmark_vertex("nose_tip"), s.landmark_vertex("chin")
    half = scale_preset(doc, 0.5)
    assert half["edits"][0]["handles"][0]["offset"] == [0.0, -1.5, 6.0]
    assert doc["edits"][0]["handles"][0]["offset"] == [0.0, -3.0, 12.0]  # the original is untouched
    doc["strength"] = 2.0  # the preset's own strength multiplies the argument's
    t = stack_for(model)
    t.apply_preset(doc, strength=1.5)
    d = t.solve()
    assert np.allclose(d[nose], 3.0 * np.array(FIG6E[0]["nose_tip"]), atol=1e-9)
    assert np.allclose(d[chin], 3.0 * np.array(FIG6E[1]["chin"]), atol=1e-9)
    assert t.edits[0].roi_radius == s.edits[0].roi_radius  # strength scales offsets, not the ROI
    assert "strength" not in t.to_preset()  # saved offsets hold it
    fresh = stack_for(model)
    fresh.apply_preset(doc, strength=0.0)
    assert np.abs(fresh.solve()).max() < 1e-6  # strength 0: the handles stay, nothing moves


@pytest.mark.parametrize("where, value", [("argument", 3.5), ("argument", -0.1), ("argument", float("nan")),
                                          ("field", 4), ("field", "strong"), ("field", True)])
def test_strength_outside_0_to_3_is_one_sentence_naming_it(model, where, value):
    from facesculpt.nodes.deformer.preset_format import scale_preset

    s = stack_for(model)
    make_edits(s, FIG6E[:1])
    doc = s.to_preset()
    before = s.to_preset()
    kwargs = {"strength": value} if where == "argument" else {}
    if where == "field":
        doc["strength"] = value
    for call in (lambda: scale_preset(doc, **kwargs), lambda: s.apply_preset(doc, **kwargs)):
        with pytest.raises(DeformerError) as err:
            call()
        message = str(err.value)
        assert repr(value) in message and "outside 0..3" in message and message.count(".") <= 3, message
    assert s.to_preset() == before


def test_presets_written_before_portable_handles_still_load(model):
    """The version-1 files older builds wrote: numeric names and vertex-only handles."""
    s = stack_for(model)
    nose, other = s.landmark_vertex("nose_tip"), 5
    old = {"format": "facesculpt-deformer-preset", "version": 1, "units": "mm",
           "topology": {"vertices": s.n, "triangles": int(model.triangles.shape[0]), "crc32": 0},
           "static": [{"vertex": 7}],
           "edits": [{"handles": [{"landmark": "nose_tip", "aliases": ["31"], "vertex": nose, "offset": [0, 0, 4]}],
                      "roi": {"radius": 40.0, "metric": "geodesic"}},
                     {"handles": [{"vertex": other, "offset": [1, 0, 0]}], "roi": {"radius": 30.0, "metric": "geodesic"}}]}
    from facesculpt.nodes.deformer.edits import topology_signature

    old["topology"] = topology_signature(s.n, model.triangles)
    s.apply_preset(old)
    d = s.solve()
    assert np.allclose(d[nose], [0, 0, 4]) and np.allclose(d[other], [1, 0, 0]) and s.static == {7}
    # an iBUG number of one model is no name on another: a numeric name from another mesh is not
    # taken at its word ("31" here would be the nose on the SFM but vertex 31 of the face mesh)
    elsewhere = json.loads(json.dumps(old))
    elsewhere["topology"]["crc32"] += 1
    elsewhere["edits"] = [{"handles": [{"landmark": "31", "vertex": 31, "offset": [0, 0, 1]}]}]
    elsewhere["static"] = []
    with pytest.raises(DeformerError, match="different mesh topology"):
        s.apply_preset(elsewhere)
    del elsewhere["topology"]  # a hand-written preset (no topology) means the names it uses
    s.apply_preset(elsewhere)
    assert list(s.edits[0].offsets) == [s.landmark_vertex("31")]


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d["edits"][0]["handles"][0].update(offset=[0, 1]), "not 3 finite numbers"),
        (lambda d: d["edits"][0]["handles"][0].update(point=[0, "x", 1]), "not 3 finite numbers"),
        (lambda d: d["edits"][0].update(handles=[]), "has no handles"),
        (lambda d: d["edits"][0]["handles"][0].pop("offset"), "no 'offset'"),
        (lambda d: d.update(edits={"a": 1}), "'edits' is not a list"),
        (lambda d: d.update(landmarks={"nose_tip": [0, 0]}), "not 3 finite numbers"),
        (lambda d: d["edits"][0]["roi"].update(metric="manhattan"), "metric"),
        (lambda d: d.update(version=2), "version"),
    ],
)
def test_validate_preset_without_a_model(model, mutate, message):
    from facesculpt.nodes.deformer.preset_format import validate_preset

    s = stack_for(model)
    s.begin([5])
    s.set_offset(5, [1.0, 0.0, 0.0])
    doc = s.to_preset()
    validate_preset(doc)
    mutate(doc)
    with pytest.raises(DeformerError, match=message):
        validate_preset(doc)


def test_find_and_read_preset_files(tmp_path):
    from facesculpt.nodes.deformer.preset_format import find_preset, read_preset_file

    shipped = find_preset("chin")
    assert shipped.name == "chin.json" and read_preset_file(shipped)["edits"]
    own = tmp_path / "chin.json"  # a file in preset_dir wins over the shipped preset
    own.write_text(shipped.read_text())
    assert find_preset("chin.json", tmp_path) == own
    with pytest.raises(DeformerError, match="not found .*shipped: cheeks, chin, nose_longer.*no file"):
        find_preset("no_such", tmp_path)
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(DeformerError, match="list.json: not a facesculpt-deformer-preset"):
        read_preset_file(tmp_path / "list.json")


def test_merge_presets_keeps_each_presets_strength_and_origin(model):
    """Presets stacked for one run (nose, then a point saved on another mesh in other units,
    then the shipped chin): each keeps its own strength, and its handles are placed through
    the landmarks of the mesh it was made on."""
    from facesculpt.nodes.deformer.preset_format import find_preset, merge_presets, read_preset_file

    s = stack_for(model)
    make_edits(s, FIG6E[:1])
    s.begin([5])
    s.set_offset(5, [2.0, 0.0, 0.0])
    here = s.to_preset()
    here["strength"] = 2.0
    there = json.loads(json.dumps(here))  # as if saved on another mesh, in units 20 times smaller than mm
    there["topology"]["crc32"] += 1
    there["landmarks"] = {k: [20.0 * x for x in p] for k, p in there["landmarks"].items()}
    for edit in there["edits"]:
        for h in edit["handles"]:
            if "point" in h:
                h["point"] = [20.0 * x for x in h["point"]]
    there["strength"] = 0.5
    chin = read_preset_file(find_preset("chin"))
    merged = merge_presets([here, there, chin], strength=1.5)
    assert "landmarks" not in merged and len(merged["edits"]) == 5
    t = stack_for(model)
    t.apply_preset(merged)
    nose, chin_v = t.landmark_vertex("nose_tip"), t.landmark_vertex("chin")
    assert [sorted(e.offsets) for e in t.edits[:4]] == [[nose], [5], [nose], [5]]
    assert chin_v in t.edits[4].offsets   # the chin's patch, placed through the face mesh's landmarks
    assert np.allclose(t.edits[1].offsets[5], [3.0 * 2.0, 0, 0])  # strength 2 x 1.5, same mesh: exact
    assert np.allclose(t.edits[3].offsets[5], [0.75 * 2.0 / 20.0, 0, 0], atol=1e-6)  # 0.5 x 1.5, in this mesh's mm
    assert np.isclose(t.edits[3].roi_radius, here["edits"][1]["roi"]["radius"] / 20.0)
    want = 1.5 * np.array(chin["edits"][0]["handles"][0]["offset"])   # scaled to this face's size, turned to its axes
    assert np.linalg.norm(t.edits[4].offsets[chin_v] - want) < 0.1 * np.linalg.norm(want)
    with pytest.raises(DeformerError, match="no preset"):
        merge_presets([])


@pytest.mark.parametrize("grip, within_mm", [(0.0, 0.1), (0.2, 0.05)])
@pytest.mark.slow
def test_a_preset_settles_on_its_arap_solution(grip, within_mm):
    """settle() solves until the mesh stops moving, as the live deformer's idle rounds do, and lands
    where a long solve does (a preset solved once for a video must not stop short of it). A
    single-vertex handle (grip 0, the default) converges more slowly (about 200 iterations against
    40 with a grip) and stops a little further from it (0.06 mm against 0.02)."""
    from facesculpt.nodes.deformer.preset_format import find_preset, read_preset_file
    from facesculpt.nodes.fitter import load_model

    face = load_model("facemesh")
    doc = read_preset_file(find_preset("cheeks"))
    settled, long = (EditStack(face.mean, face.triangles, face.landmark_names, face.landmark_vertices, grip=grip)
                     for _ in range(2))
    for s in (settled, long):
        s.apply_preset(doc)
    got = settled.settle()
    assert settled.deformer.last_converged
    assert settled.deformer.last_iterations < 400   # the cap it had before the refined solve mesh
    assert settled.deformer.tolerance == 0.0   # only this solve ran to the tolerance
    assert np.abs(got - long.solve(2000)).max() < within_mm


def test_the_shipped_chin_at_strength_2_moves_the_chin_with_its_neighbours_not_to_a_point():
    """Issue 51: the chin preset pulled one vertex, and at strength 2 ARAP drew a cusp (a pointed V);
    it now moves the chin's patch of skin as one, so the chin moves about as its ring of neighbours does."""
    from facesculpt.nodes.deformer.preset_format import find_preset, read_preset_file
    from facesculpt.nodes.fitter import load_model

    m = load_model("facemesh")
    s = EditStack(m.mean, m.triangles, m.landmark_names, m.landmark_vertices)
    s.apply_preset(read_preset_file(find_preset("chin")), 2.0)
    d = s.solve()
    chin = s.landmark_vertex("chin")
    ring = np.setdiff1d(m.triangles[(m.triangles == chin).any(1)], [chin])
    # the single-vertex chin: its ring lagged by half of the chin's motion
    assert np.linalg.norm(d[chin] - d[ring].mean(0)) < 0.2 * np.linalg.norm(d[chin])
    assert np.linalg.norm(d[chin]) > 15.0   # and the chin did move (2 x 10.8 mm)


def test_the_shipped_cheeks_at_strength_2_leave_the_nose_as_it_is():
    """Issue 51: with only the nose's tip and bridge pinned, cheeks at strength 2 pulled the alae
    4 mm in and back (the pinched nose on d0); the whole nose is pinned now, the cheeks still move."""
    from facesculpt.nodes.deformer.preset_format import find_preset, read_preset_file
    from facesculpt.nodes.fitter import load_model

    m = load_model("facemesh")
    s = EditStack(m.mean, m.triangles, m.landmark_names, m.landmark_vertices)
    s.apply_preset(read_preset_file(find_preset("cheeks")), 2.0)
    d = s.solve()
    alae = [48, 64, 98, 278, 294, 327]   # the face mesh's nose wings, both sides
    assert np.linalg.norm(d[alae], axis=1).max() < 0.5
    for cheek in ("left_cheek", "right_cheek"):
        assert np.linalg.norm(d[s.landmark_vertex(cheek)]) > 15.0   # 2 x 8.5 mm
