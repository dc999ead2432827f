"""The learned expression classifier (issue 48): Newton's logistic regression separates what is
separable; the packaged weights load with their provenance and fit the recogniser's features; the
weights are JSON that reads back bit for bit, and an old .npz weights file still loads (warning
once) and converts; a bad weights file is refused in one sentence (recogniser, pipeline); held-out renders of the
expressions (an identity, texture and background no training render had) are labelled right
where the classifier can tell them (four of six and neutral)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from facesculpt.nodes.fitter.expression import NAMES
from facesculpt.nodes.fitter.expression_classifier import (
    KINDS,
    WEIGHTS,
    ExpressionClassifier,
    convert_npz_weights,
    feature_vector,
    fit_logistic,
    load_classifiers,
    provenance,
    save_classifiers,
)
from facesculpt.nodes.fitter.expression_labels import EXPRESSIONS, LABELS, ExpressionRecogniser


def test_logistic_regression_finds_three_separated_classes():
    rng = np.random.default_rng(3)
    centres = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    y = rng.integers(0, 3, 600)
    X = centres[y] + rng.normal(0, 0.7, (600, 2))
    W, b = fit_logistic(X, y, 3, l2=1e-3)
    c = ExpressionClassifier(("a", "b"), np.zeros(2), np.ones(2), W, b, ("x", "y", "z"))
    P = c.probabilities(X)
    assert P.shape == (600, 3) and np.allclose(P.sum(axis=1), 1.0)
    assert np.mean(P.argmax(axis=1) == y) > 0.95
    assert c.probabilities(np.array([4.0, 0.0])).argmax() == 1   # one vector in, one row out


def test_the_packaged_weights_load_with_their_provenance():
    classifiers = load_classifiers()
    assert set(classifiers) == set(KINDS)
    for kind, c in classifiers.items():
        assert c.labels == LABELS and c.weights.shape == (len(LABELS), len(c.features))
        assert set(NAMES) <= set(c.features), kind
    assert {f"beta:{e}" for e in EXPRESSIONS} <= set(classifiers["blendshapes"].features)
    assert json.loads(WEIGHTS.read_text())["format"] == "facesculpt expression classifier"   # text, not binary
    record = provenance()
    assert record["command"].startswith("python -m benchmarks.train_expression_classifier")
    assert record["held_out"] and record["frames"] > 0
    # the recogniser's features: parameters by name, coefficients by their expression's name in any case
    x = feature_vector(("jaw_open", "beta:anger", "missing"), np.arange(len(NAMES)), NAMES, [0.5], ["Anger"])
    assert x.tolist() == [0.0, 0.5, 0.0]


def test_a_bad_weights_file_is_refused_in_one_sentence(tmp_path):
    c = load_classifiers()["parameters"]
    good = {"features": list(c.features), "labels": list(c.labels), "mean": c.mean.tolist(),
            "scale": c.scale.tolist(), "weights": c.weights.tolist(), "bias": c.bias.tolist()}
    contents = {
        "junk.json": "not JSON", "junk.npz": "PK\x03\x04 not a zip", "list.json": "[1, 2]",
        "other.json": json.dumps({"classifiers": {"parameters": good}}),   # no format: some other JSON
        "none.json": json.dumps({"format": "facesculpt expression classifier", "classifiers": {}}),
        "lacks.json": json.dumps({"format": "facesculpt expression classifier",
                                  "classifiers": {"parameters": {k: v for k, v in good.items() if k != "bias"}}}),
        "words.json": json.dumps({"format": "facesculpt expression classifier",
                                  "classifiers": {"parameters": {**good, "mean": "x"}}}),
    }
    for name, text in contents.items():
        (tmp_path / name).write_text(text)
    messages = {}
    for path in (*(tmp_path / name for name in contents), tmp_path / "absent.json", tmp_path):
        with pytest.raises(ValueError, match="cannot use the classifier weights") as err:
            ExpressionRecogniser(weights=str(path))
        assert "\n" not in str(err.value), path
        messages[path.name] = str(err.value)
    assert messages["lacks.json"].endswith("its parameters classifier lacks bias")
    broken = tmp_path / "broken.json"   # the weights of one feature too few
    save_classifiers(broken, {"parameters": ExpressionClassifier(c.features, c.mean, c.scale, c.weights[:, :-1],
                                                                 c.bias, c.labels)}, {})
    with pytest.raises(ValueError, match="do not fit together"):
        ExpressionRecogniser(source="learned", weights=str(broken))
    ExpressionRecogniser(source="facs", weights=str(broken))   # the rules need no weights


def test_the_weights_read_back_bit_for_bit(tmp_path):
    """Values JSON's shortest float repr must carry exactly: extremes, subnormals, negative zero."""
    rng = np.random.default_rng(5)
    F = 4
    odd = np.array([5e-324, -0.0, 1.7976931348623157e308, 0.1 + 0.2])
    c = ExpressionClassifier(("a", "b", "beta:anger", "é"), rng.normal(size=F) * 1e-7, np.abs(rng.normal(size=F)) + odd[0],
                             np.vstack([odd, rng.normal(size=(2, F)) * 1e12]), rng.normal(size=3), ("x", "y", "z"),
                             pose_bias=rng.normal(size=(5, F)) / 3.0)
    save_classifiers(tmp_path / "w.json", {"blendshapes": c}, {"command": "a test", "frames": 3})
    got = load_classifiers(tmp_path / "w.json")["blendshapes"]
    assert (got.features, got.labels) == (c.features, c.labels)
    for field in ("mean", "scale", "weights", "bias", "pose_bias"):
        a, b = getattr(c, field), getattr(got, field)
        assert b.dtype == np.float64 and np.array_equal(a.view(np.uint64), b.view(np.uint64)), field
    assert provenance(tmp_path / "w.json") == {"command": "a test", "frames": 3}
    with pytest.raises(ValueError):   # NaN is not JSON: refused when written, not written as NaN
        save_classifiers(tmp_path / "nan.json", {"parameters": ExpressionClassifier(
            ("a",), np.array([np.nan]), np.ones(1), np.ones((1, 1)), np.zeros(1), ("x",))}, {})


def test_an_old_npz_weights_file_still_loads_with_one_warning_and_converts(tmp_path):
    """An .npz laid out as the training script wrote it before the weights were JSON."""
    packaged, record = load_classifiers(), provenance()
    arrays = {"provenance": np.array(json.dumps(record, indent=1))}
    for kind, c in packaged.items():
        arrays.update({f"{kind}.features": np.array(c.features), f"{kind}.mean": c.mean, f"{kind}.scale": c.scale,
                       f"{kind}.weights": c.weights, f"{kind}.bias": c.bias, f"{kind}.labels": np.array(c.labels)})
    old = tmp_path / "mine.npz"
    np.savez_compressed(old, **arrays)
    with pytest.warns(DeprecationWarning, match="convert it to JSON once") as caught:
        recogniser = ExpressionRecogniser(source="learned", weights=str(old))
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # once: a second recogniser on the same file says nothing
        ExpressionRecogniser(source="learned", weights=str(old))
    for kind, c in recogniser.classifiers.items():
        assert np.array_equal(c.weights, packaged[kind].weights) and c.features == packaged[kind].features
    assert provenance(old) == record

    converted = convert_npz_weights(old)
    assert converted == tmp_path / "mine.json"
    for kind, c in load_classifiers(converted).items():
        assert np.array_equal(c.weights.view(np.uint64), packaged[kind].weights.view(np.uint64))
    assert provenance(converted)["command"] == record["command"] and "converted" in provenance(converted)
    before = converted.read_bytes()
    with pytest.raises(FileExistsError):   # a user's file is never overwritten
        convert_npz_weights(old)
    assert converted.read_bytes() == before


def test_a_pipeline_with_a_bad_weights_file_stops_before_the_first_frame(models_dir, tmp_path):
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions

    with pytest.raises(ValueError, match="cannot use the classifier weights"):
        Pipeline("facemesh", expression_labels=ExpressionLabelOptions(weights=str(tmp_path / "absent.json")))


@pytest.mark.slow
def test_a_held_out_render_of_each_expression_is_labelled(models_dir, data_dir):
    """A photo and an identity no training render had (Tom_Cruise_avp_2014_4.jpg, seed 131), the SFM fit:
    rested over a few turning frames, then each expression at weight 0.9 rising over RAMP frames,
    labelled by the packaged classifier (the SFM's default source) on its last frame."""
    from benchmarks.bench_expression_labels import RAMP, render
    from benchmarks.train_expression_classifier import training_scene
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.config import FitterConfig
    from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions

    rest_frames = 8
    scene = training_scene(data_dir, 131, data_dir / "faces" / "Tom_Cruise_avp_2014_4.jpg")
    basis = np.asarray(load_model("sfm").expression_basis, np.float64)
    labels = ExpressionLabelOptions(baseline_frames=rest_frames, window_s=0.0)
    got = {}
    with Pipeline("sfm", fit=FitterConfig(neutral_frames=rest_frames), expression_labels=labels) as pipe:
        t = 0.0
        for i in range(rest_frames):
            pipe.fit_frame(render(scene, basis, np.zeros(6), 6.0 * np.sin(i), 3.0), t)
            t += 0.04
        for e, expression in enumerate((*EXPRESSIONS, "neutral")):
            for j in range(RAMP):
                weights = np.zeros(6)
                if expression != "neutral":
                    weights[e] = 0.9 * (j + 1) / RAMP
                fit = pipe.fit_frame(render(scene, basis, weights, 10.0, -4.0), t)
                t += 0.04
            got[expression] = fit.expression_label.label
            for _ in range(2):   # back to rest
                pipe.fit_frame(render(scene, basis, np.zeros(6), 10.0, -4.0), t)
                t += 0.04
    # anger and sadness, the SFM's subtlest, are read as neutral here (and mostly on the benchmark:
    # docs/results/expressions.md); the other four and the rest are right
    recognised = ("disgust", "fear", "happiness", "surprise", "neutral")
    assert {e: got[e] for e in recognised} == {e: e for e in recognised}, got
