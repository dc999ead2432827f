"""Expressions recognised (issue 48): the FACS table names real components and action units and
ranks each basic expression first on its own prototype; the recogniser learns the resting face,
says neutral on it, follows a new expression from onset to apex, holds a label against a close rival, reads a blendshape model's named
coefficients; the message carries the label and still decodes without it; the window's overlay
parameter is parsed and refused in one sentence, and the expression is drawn above the face."""

from __future__ import annotations

import json

import msgpack
import numpy as np
import pytest

from facesculpt.nodes.fitter.expression import NAMES
from facesculpt.nodes.fitter.expression_labels import (
    ACTION_UNITS,
    EXPRESSIONS,
    LABELS,
    PROTOTYPES,
    ExpressionRecogniser,
    action_units,
    facs_scores,
    table_rows,
)

UNITS = list(ACTION_UNITS)


def au_matrix() -> np.ndarray:
    """(U, E) activation of each action unit per unit of each named component."""
    A = np.zeros((len(UNITS), len(NAMES)))
    for k in range(len(NAMES)):
        v = np.zeros(len(NAMES))
        v[k] = 1.0
        A[:, k] = [action_units(v, NAMES)[u] for u in UNITS]
    return A


def prototype_values(expression: str, strength: float = 1.0) -> np.ndarray:
    """(E,) the smallest expression parameters that mark every prototype unit of ``expression``
    at ``strength`` (the others free: whatever the anatomy of the components makes them)."""
    A = au_matrix()
    rows = [UNITS.index(u) for u in PROTOTYPES[expression][0]]
    values, *_ = np.linalg.lstsq(A[rows], np.full(len(rows), strength), rcond=None)
    return values


def test_the_table_names_components_and_units_that_exist():
    for unit, (text, terms, full) in ACTION_UNITS.items():
        assert unit.startswith("AU") and text and full > 0
        assert set(terms) <= set(NAMES), unit
    for expression in EXPRESSIONS:
        units, against = PROTOTYPES[expression]
        assert units and set(units) | set(against) <= set(ACTION_UNITS)
        assert not set(units) & set(against), expression
    assert [r[0] for r in table_rows()] == UNITS and all("/" in r[2] for r in table_rows())


@pytest.mark.parametrize("expression", EXPRESSIONS)
def test_each_prototype_ranks_its_own_expression_first(expression):
    values = prototype_values(expression)
    a = action_units(values, NAMES)
    assert all(a[u] == pytest.approx(1.0, abs=1e-6) for u in PROTOTYPES[expression][0])
    scores = facs_scores(values, NAMES)
    assert EXPRESSIONS[int(np.argmax(scores))] == expression, dict(zip(EXPRESSIONS, np.round(scores, 2)))
    assert np.allclose(facs_scores(np.zeros(len(NAMES)), NAMES), 0.0)


def test_recogniser_learns_the_resting_face_then_follows_an_expression():
    rec = ExpressionRecogniser(source="facs", baseline_frames=5, window_s=0.1, neutral_below=0.25, switch_margin=0.05)
    rest = prototype_values("sadness", 0.5)  # a resting face with its corners down is this person's neutral
    t = 0.0
    for _ in range(5):
        assert rec.update(t, rest, NAMES).label == "neutral"
        t += 0.04
    for _ in range(4):
        out = rec.update(t, rest, NAMES)
        t += 0.04
    assert out.label == "neutral" and out.intensity == pytest.approx(1.0) and out.scores.shape == (len(LABELS),)
    happy = rest + prototype_values("happiness", 0.8)
    first = rec.update(t, happy, NAMES)
    assert first.phase == "onset"
    for _ in range(4):
        t += 0.04
        out = rec.update(t, happy, NAMES)
    assert out.label == "happiness" and out.phase == "apex" and 0.5 < out.intensity <= 1.0
    for _ in range(4):
        t += 0.04
        out = rec.update(t, rest + prototype_values("surprise", 1.0), NAMES)
    assert out.label == "surprise"
    rec.reset()
    assert rec.update(0.0, rest, NAMES).label == "neutral" and rec.seen == 1


def test_a_blendshape_model_is_read_by_name_and_a_label_is_held():
    names = ["Happiness", "anger", "disgust", "fear", "sadness", "surprise"]  # any order, any case
    rec = ExpressionRecogniser(source="blendshapes", baseline_frames=2, window_s=0.0)
    zeros = np.zeros(len(NAMES))
    for k in range(2):
        rec.update(k * 0.04, zeros, NAMES, np.array([0.0, 0.3, 0, 0, 0, 0]), names)  # rests at anger 0.3
    out = rec.update(0.08, zeros, NAMES, np.array([0.0, 0.9, 0, 0, 0, 0]), names)
    assert out.label == "anger" and out.intensity == pytest.approx(0.6, abs=1e-6)
    out = rec.update(0.12, zeros, NAMES, np.array([0.7, 0.3, 0, 0, 0, 0]), names)
    assert out.label == "happiness"
    # a rival a little stronger does not take the label; a clearly stronger one does
    rec = ExpressionRecogniser(source="blendshapes", baseline_frames=0, window_s=0.0, switch_margin=0.1)
    assert rec.update(0.0, zeros, NAMES, np.array([0.0, 0.6, 0, 0, 0, 0]), names).label == "anger"
    assert rec.update(0.04, zeros, NAMES, np.array([0.0, 0.6, 0.65, 0, 0, 0]), names).label == "anger"
    assert rec.update(0.08, zeros, NAMES, np.array([0.0, 0.6, 0.75, 0, 0, 0]), names).label == "disgust"
    with pytest.raises(ValueError, match="source=blendshapes needs a model"):
        ExpressionRecogniser(source="blendshapes", baseline_frames=0).update(0.0, zeros, NAMES, np.zeros(3), [])
    with pytest.raises(ValueError, match="source must be"):
        ExpressionRecogniser(source="svm")


def test_the_message_carries_the_label_and_decodes_without_it():
    from facesculpt.msgs import FaceExpression
    from facesculpt.msgs.codec import decode, encode
    from facesculpt.nodes.foxglove.convert import expression_json

    scores = np.linspace(0, 0.6, 7).astype(np.float32)
    msg = FaceExpression(stamp=5, face_id=1, names=list(NAMES), values=np.arange(len(NAMES), dtype=np.float32),
                         label="surprise", intensity=0.7, phase="onset", label_scores=scores)
    _, back = decode(encode(msg, "face/expression"))
    assert back.label == "surprise" and back.intensity == pytest.approx(0.7) and back.phase == "onset"
    assert np.array_equal(back.label_scores, scores)
    # a sender from before the labels: its header has none of their fields
    frames = encode(FaceExpression(stamp=5, names=list(NAMES), values=np.zeros(len(NAMES), np.float32)),
                    "face/expression")
    header = msgpack.unpackb(frames[1])
    for name in ("label", "intensity", "phase"):
        del header["f"][name]
    _, back = decode([frames[0], msgpack.packb(header), *frames[2:]])
    assert back.label == "" and back.intensity == 0.0 and back.label_scores is None
    doc = json.loads(json.dumps(expression_json(msg)))
    assert doc["label"] == "surprise" and doc["scores"]["neutral"] == pytest.approx(0.6)
    assert doc["values"][NAMES[3]] == 3.0 and set(doc["pose"]) >= {"yaw_deg", "tz_mm"}


def test_overlay_names_are_parsed_and_an_unknown_one_is_refused():
    from facesculpt.nodes.renderer.overlay_layers import parse_overlay

    assert parse_overlay("info") == {"info"} and parse_overlay(True) == {"info"} and parse_overlay("on") == {"info"}
    assert parse_overlay("gaze, expression") == {"gaze", "expression"}
    assert parse_overlay("off") == set() and parse_overlay(False) == set() and parse_overlay("") == set()
    with pytest.raises(ValueError) as err:
        parse_overlay("expression,smile")
    assert "smile" in str(err.value) and "\n" not in str(err.value) and "gaze" in str(err.value)


def test_an_unknown_overlay_is_refused_with_the_parameters():
    from facesculpt.nodes.renderer.node import RendererNode
    from facesculpt.runtime.parameters import ParameterError, resolve_params

    with pytest.raises(ParameterError, match="renderer.overlay='info,expresion' names an unknown layer: expresion"):
        resolve_params("renderer", RendererNode.PARAMS, {"overlay": "info,expresion"})
    assert resolve_params("renderer", RendererNode.PARAMS, {"overlay": "gaze,expression"})["overlay"]


@pytest.mark.slow
def test_launch_check_refuses_an_unknown_overlay_in_one_sentence():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "facesculpt.cli", "launch", "webcam", "renderer.overlay=smile",
                        "--check"], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "names an unknown layer: smile" in r.stderr and len(r.stderr.splitlines()) == 1


def test_the_expression_is_drawn_above_the_face():
    from facesculpt.msgs import FaceExpression
    from facesculpt.nodes.renderer.overlay_layers import DRAWERS, face_box

    frame = np.full((240, 320, 3), 90, np.uint8)
    projected = np.array([[120.0, 100.0], [200.0, 100.0], [160.0, 200.0], [np.nan, np.nan]])
    box = face_box(projected, 320, 240)
    assert box == (120, 100, 200, 200)
    msg = FaceExpression(label="happiness", intensity=0.7)
    out = DRAWERS["expression"](frame, box, msg)
    changed = np.argwhere((out != frame).any(axis=2))
    assert len(changed) > 50 and changed[:, 0].max() < 100 and changed[:, 0].min() > 60  # a line just above it
    assert np.array_equal(DRAWERS["expression"](frame, box, FaceExpression()), frame)  # no label: nothing
    top = DRAWERS["expression"](frame, (120, 2, 200, 100), msg)  # no room above: drawn inside the top edge
    assert (top != frame).any(axis=2)[2:60].any()


def test_labels_from_blendshapes_are_refused_for_a_model_without_them(models_dir):
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions

    with pytest.raises(ValueError, match="need a model whose blendshapes are named"):
        Pipeline("facemesh", expression_labels=ExpressionLabelOptions(source="blendshapes"))


def test_the_gaze_layer_draws_the_rays_through_the_frames_intrinsics():
    from facesculpt.msgs import FaceGaze
    from facesculpt.nodes.renderer.overlay_layers import DRAWERS

    frame = np.zeros((240, 320, 3), np.uint8)
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    msg = FaceGaze(centres=np.array([[-30, 0, 500], [30, 0, 500]], np.float32),
                   directions=np.array([[0.5, 0, -0.866], [0.5, 0, -0.866]], np.float32),
                   closed=np.zeros(2, np.uint8))
    drawn = DRAWERS["gaze"](frame, (100, 50, 220, 200), msg, K)
    assert (drawn != frame).any()
    assert np.array_equal(DRAWERS["gaze"](frame, (100, 50, 220, 200), msg, None), frame)  # no K: nothing
