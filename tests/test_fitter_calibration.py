"""The landmark calibration of a model (facesculpt/nodes/fitter/calibration.py, issue 46): where the
network's points lie off the model's landmark vertices, learned at known pose, kept with the model
and used by the sparse fitter."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter.calibration import (
    calibrated,
    learn_calibration,
    load_calibration,
    project_model,
    save_calibration,
    triangulate,
)
from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel, save_model
from facesculpt.nodes.fitter.pose import rotation_from_euler, rotation_log

K = np.array([[560.0, 0, 320], [0, 560.0, 240], [0, 0, 1]])


def _poses(frames: int):
    R = np.array([rotation_from_euler(25 * np.sin(i / 6), 10 * np.sin(i / 4), 0) for i in range(frames)])
    c = np.tile([0.0, 0.0, 520.0], (frames, 1))
    return R, c


def test_a_point_off_its_vertex_is_found_from_its_images_at_known_pose():
    rng = np.random.default_rng(3)
    vertices = rng.normal(0, 35, (12, 3))
    offsets = rng.normal(0, 4, (12, 3))
    sequences = []
    for _ in range(2):   # two people: another head, the same offsets
        head = vertices + rng.normal(0, 3, vertices.shape)
        R, c = _poses(40)
        seen = project_model(K, R, c, head + offsets) + rng.normal(0, 0.3, (40, 12, 2))
        seen[5, 3] = np.nan   # a point missed in one frame
        sequences.append({"K": K, "R": R, "c": c, "observed": seen, "vertices": head})
    X = triangulate(K, R, c, seen)
    assert np.abs(X - (head + offsets)).max() < 1.0
    learned = learn_calibration(sequences)
    assert np.abs(learned["offsets"] - offsets).max() < 1.0
    assert np.all(learned["sigma"] < 0.6) and abs(learned["weights"].mean() - 1.0) < 1e-6
    with pytest.raises(ValueError, match="at least one"):
        learn_calibration([])


def _toy_model() -> MorphableModel:
    rng = np.random.default_rng(4)
    mean = rng.normal(0, 40, (30, 3)).astype(np.float32)
    return MorphableModel(model_id="toy", mean=mean, triangles=np.array([[0, 1, 2], [2, 3, 4]], np.int32),
                          landmark_names=[str(i) for i in range(1, 21)], landmark_vertices=np.arange(20, dtype=np.int32))


def test_a_calibration_is_kept_with_its_model_and_refused_for_another(tmp_path):
    model = _toy_model()
    offsets, weights = np.full((2, 3), 2.5), np.array([0.5, 2.0])
    file = save_calibration(tmp_path / "c.npz", "toy", ["3", "7"], offsets, weights, "made in a test")
    got = load_calibration(file, model)
    assert got.calibration == "made in a test"
    assert np.allclose(got.landmark_offsets[[2, 6]], 2.5) and np.allclose(got.landmark_offsets[[0, 1, 3]], 0.0)
    assert np.allclose(got.landmark_weights[[2, 6]], [0.5, 2.0]) and got.landmark_weights[0] == 1.0
    again = load_model(save_model(got, tmp_path / "m.npz"))   # the .npz model keeps it
    assert again.calibration == "made in a test" and np.allclose(again.landmark_offsets, got.landmark_offsets)
    with pytest.raises(ModelFormatError, match="not 'other'"):
        load_calibration(file, dataclasses.replace(model, model_id="other"))
    with pytest.raises(ValueError, match="no landmark named 99"):
        calibrated(model, ["99"], offsets[:1], weights[:1], "")
    with pytest.raises(ModelFormatError, match="landmark_weights"):
        dataclasses.replace(model, landmark_weights=np.zeros(20, np.float32))


def test_the_sparse_fit_finds_the_pose_of_points_that_lie_off_their_vertices(data_dir):
    """Points that lie 4 mm off the SFM's landmark vertices, in depth alike: fitted with the
    calibration that says so, the head's rotation is found; without it, it is not."""
    sfm = load_model("sfm")
    names = [n for n in sfm.landmark_names if n.isdigit() and n != "9"]
    index = sfm.landmark_index()
    rng = np.random.default_rng(5)
    offsets = rng.normal(0, 4.0, (len(names), 3))
    points = np.array([sfm.mean[index[n]] for n in names], np.float64) + offsets
    plain = dataclasses.replace(sfm, landmark_offsets=np.zeros((0, 3), np.float32),
                                landmark_weights=np.zeros(0, np.float32), calibration="")
    errors = {}
    for label, model in (("plain", plain), ("calibrated", calibrated(plain, names, offsets, np.ones(len(names)), "test"))):
        worst = 0.0
        for yaw, pitch in ((25, 0), (-20, 10), (0, -12)):
            R = rotation_from_euler(yaw, pitch, 0)
            x = project(points @ R.T + [0.0, 0.0, 550.0], K)
            config = FitterConfig(smoothing=False, accumulate_identity=False, rotation_prior_px=0.0, iterations=8)
            fit = make_fitter(model, config, (640, 480), K).fit(x, names)
            worst = max(worst, np.degrees(np.linalg.norm(rotation_log(np.asarray(fit.R).T @ R))))
        errors[label] = worst
    assert errors["calibrated"] < 0.5 < errors["plain"], errors


def test_a_network_that_turns_short_of_the_head_is_scaled_by_its_gain():
    from facesculpt.nodes.fitter.detector_rotation import DetectorRotation

    rng = np.random.default_rng(6)
    head = rng.normal(0, 30, (13, 3))
    plain, gained = DetectorRotation(reference_frames=1), DetectorRotation(reference_frames=1, gain=(1.25, 1.0, 1.0))
    for net in (plain, gained):
        net.observe(head @ rotation_from_euler(0, 0, 0).T)   # the reference: the head facing the camera
    turned = head @ rotation_from_euler(0, 0.8 * 15.0, 0).T   # the network's points turn 0.8 of a 15 degree nod
    short, full = plain.observe(turned), gained.observe(turned)
    angle = lambda R: np.degrees(np.linalg.norm(rotation_log(R)))  # noqa: E731
    assert abs(angle(short) - 12.0) < 0.01 and abs(angle(full) - 15.0) < 0.01
