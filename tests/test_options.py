"""Every option declared once (issue 47): the options dataclasses beside their algorithms carry
each option's default, unit, range and help, and the node parameters, the command line and the
in-process pipeline derive from them, so they cannot disagree."""

from __future__ import annotations

import dataclasses
import logging
import math
import warnings

import pytest

from facesculpt.app.pipeline_options import OLD_NAMES, options_of_old_names
from facesculpt.cli import build_parser
from facesculpt.geometry.detector_options import DetectorOptions
from facesculpt.nodes.camera.intrinsics import IntrinsicsOptions
from facesculpt.nodes.camera.node import CameraNode
from facesculpt.nodes.deformer.deformer_options import DeformerOptions
from facesculpt.nodes.deformer.edits import Edit, EditStack
from facesculpt.nodes.deformer.node import DeformerNode
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions
from facesculpt.nodes.fitter.node import FITTER_PARAMS, FitterNode
from facesculpt.nodes.fitter.result import FitError
from facesculpt.nodes.fitter.stage import StageOptions
from facesculpt.nodes.hands.detector import HAND_ALIASES, HAND_OPTIONS
from facesculpt.nodes.hands.node import HandsNode
from facesculpt.nodes.landmarks.detector import FACE_ALIASES, FACE_OPTIONS
from facesculpt.nodes.landmarks.irises import IrisOptions
from facesculpt.nodes.landmarks.node import LandmarksNode
from facesculpt.nodes.renderer.compositor_options import CompositorOptions
from facesculpt.nodes.renderer.node import LIVE, RendererNode
from facesculpt.options import check_options, described_fields, option_problem
from facesculpt.runtime.parameters import Renamed, declared, resolve_params

OPTIONS_CLASSES = (DetectorOptions, FitterConfig, CompositorOptions, DeformerOptions, ExpressionLabelOptions,
                   IntrinsicsOptions, IrisOptions, StageOptions)
# node -> (the options instance its defaults come from, aliases: node name -> field); a second
# options class of the same node in SECOND_OPTIONS
SECOND_OPTIONS = [(FitterNode, StageOptions(), {})]
NODE_OPTIONS = {
    LandmarksNode: (FACE_OPTIONS, FACE_ALIASES),
    HandsNode: (HAND_OPTIONS, HAND_ALIASES),
    FitterNode: (FitterConfig(), {}),
    RendererNode: (LIVE, {}),
    DeformerNode: (DeformerOptions(), {}),
    CameraNode: (IntrinsicsOptions(), {}),
}


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@pytest.mark.parametrize("cls", OPTIONS_CLASSES, ids=lambda c: c.__name__)
def test_every_option_has_help_and_numbers_have_a_range(cls):
    fields = described_fields(cls)
    assert len(fields) == len(dataclasses.fields(cls)), "every field is declared with option()"
    for f in fields:
        assert len(f.metadata["help"]) > 10, f.name
        default = f.default
        if _is_number(default) or (default is None and f.metadata.get("range")):
            assert f.metadata.get("range") is not None, f"{cls.__name__}.{f.name} has no range"
        if f.metadata.get("choices") is not None and default is not None:
            assert default in f.metadata["choices"], f.name
        assert not option_problem(f, default), f"{cls.__name__}.{f.name}'s default is out of its own range"


def _agrees(param_default, field_default) -> bool:
    """A node value of the field's: the same, on/off for a bool, off for None, or auto (the node
    resolves it by the frame's size)."""
    if param_default == "auto":
        return True
    if isinstance(field_default, bool):
        return param_default in (field_default, "on" if field_default else "off")
    if field_default is None:
        return param_default in (None, "off") or _is_number(param_default)
    return param_default == field_default


@pytest.mark.parametrize("node, options, aliases", [(n, *NODE_OPTIONS[n]) for n in NODE_OPTIONS] + SECOND_OPTIONS,
                         ids=lambda v: getattr(v, "NAME", type(v).__name__))
def test_node_parameters_agree_with_their_options(node, options, aliases):
    fields = {f.name: f for f in dataclasses.fields(options)}
    shared = 0
    for name, param in declared(node.PARAMS).items():
        field_name = aliases.get(name, name)
        if field_name not in fields:
            continue
        shared += 1
        f = fields[field_name]
        value = getattr(options, field_name)
        assert _agrees(param.default, value), f"{node.NAME}.{name}: {param.default!r} against {value!r}"
        if param.default == value and f.metadata.get("range") is not None:
            assert param.range == f.metadata["range"], f"{node.NAME}.{name}'s range"
        if param.default == value and f.metadata.get("choices") is not None:
            assert tuple(param.choices) == tuple(f.metadata["choices"]), f"{node.NAME}.{name}'s choices"
        assert param.description, f"{node.NAME}.{name} has no help"
    assert shared >= 1


def test_the_fitter_nodes_config_is_its_parameters():
    node = FitterNode.__new__(FitterNode)
    values = resolve_params("fitter", FitterNode.PARAMS, {"iterations": "7", "smooth_min_cutoff": "2.5",
                                                          "refine": "appearance"})
    node.params = type("P", (), values)
    config = FitterNode.fitter_config(node)
    assert (config.iterations, config.smooth_min_cutoff, config.refine) == (7, 2.5, "appearance")
    assert set(FITTER_PARAMS) <= set(values)


def test_an_old_parameter_name_still_works_and_warns(caplog):
    assert isinstance(FitterNode.PARAMS["min_cutoff"], Renamed)
    with caplog.at_level(logging.WARNING, logger="facesculpt"):
        values = resolve_params("fitter", FitterNode.PARAMS, {"min_cutoff": "0.7"})
    assert values["smooth_min_cutoff"] == 0.7 and "min_cutoff" not in values
    assert "now called smooth_min_cutoff" in caplog.text


def test_a_fitter_config_out_of_its_declared_range_is_refused():
    for f in described_fields(FitterConfig):
        lo = (f.metadata.get("range") or (None, None))[0]
        if lo is None or not _is_number(lo):
            continue
        below = lo - 1 if isinstance(lo, int) and f.type.startswith("int") else lo - max(abs(lo), 1e-3)
        with pytest.raises(FitError, match=f.name):
            FitterConfig(**{f.name: below})


def test_check_options_names_the_field():
    with pytest.raises(ValueError, match="feather_px"):
        check_options(dataclasses.replace(CompositorOptions(), feather_px=-1.0))
    with pytest.raises(ValueError, match="inpaint"):
        check_options(dataclasses.replace(CompositorOptions(), inpaint="smear"))
    assert math.isclose(LIVE.feather_px, CompositorOptions().feather_px)


def _process_args(*extra):
    return build_parser(["process"]).parse_args(["process", "in.mp4", "-o", "out.mp4", *extra])


def test_the_process_flags_take_their_defaults_from_the_options():
    args = _process_args()
    fit, render = FitterConfig(), CompositorOptions()
    assert args.neutral_frames == fit.neutral_frames and args.rotation_prior == fit.rotation_prior_px
    assert args.refine == "off" and fit.refine is None and args.fov == IntrinsicsOptions().fov_deg
    assert args.threads == FACE_OPTIONS.threads
    assert (args.inpaint, args.interpolation, args.outline_band) == (render.inpaint, render.interpolation,
                                                                     render.outline_band)


def test_a_process_flag_out_of_range_is_one_sentence(capsys):
    with pytest.raises(SystemExit) as stop:
        _process_args("--rotation-prior", "-1")
    assert stop.value.code == 2
    assert "--rotation-prior: must be in [0.0, 10000.0], got -1.0" in capsys.readouterr().err


def test_the_old_fill_flag_still_works_and_warns(capsys):
    assert _process_args("--fill", "pushpull").inpaint == "pushpull"
    assert "--fill is now --inpaint" in capsys.readouterr().err


def test_the_pipelines_old_keywords_map_to_the_options_and_warn():
    given = {"neutral_frames": 9, "refine": "appearance", "inpaint": "pushpull", "outline_band": 0.1}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit, render = options_of_old_names(FitterConfig(), CompositorOptions(), given)
    assert (fit.neutral_frames, fit.refine, render.inpaint, render.outline_band) == (9, "appearance", "pushpull", 0.1)
    assert any(issubclass(w.category, DeprecationWarning) for w in caught)
    assert set(OLD_NAMES) <= {f.name for f in dataclasses.fields(FitterConfig)} | {
        f.name for f in dataclasses.fields(CompositorOptions)}
    with pytest.raises(TypeError, match="unexpected keyword"):
        options_of_old_names(FitterConfig(), CompositorOptions(), {"feather": 1})


def test_the_edit_stacks_defaults_are_the_deformers_options():
    import inspect

    options, signature = DeformerOptions(), inspect.signature(EditStack)
    for name in ("roi_radius", "roi_metric", "grip", "min_solve_vertices"):
        assert signature.parameters[name].default == getattr(options, name), name
    assert (Edit().roi_radius, Edit().roi_metric) == (options.roi_radius, options.roi_metric)
