"""Declared node parameters (facesculpt.runtime.parameters): descriptions and ranges or choices
on every built-in node, `run NODE --help` listing them, a bad value stopping a real node process
in one sentence with exit code 2, and the launcher not respawning a node that exited 2."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
import yaml
from conftest import REPO_ROOT

from facesculpt.geometry.axes_velocity import DEADZONE, DEADZONE_RANGE, SPEED_MM_S, SPEED_MM_S_RANGE
from facesculpt.nodes import BUILTIN_NODES
from facesculpt.runtime.node import Node, load_node_class, params_help
from facesculpt.runtime.parameters import EXIT_BAD_PARAMETER, Param, ParameterError, declared, resolve_params

# String parameters with a fixed set of values: each must declare its choices.
CHOICE_PARAMS = {("fitter", "projection"), ("fitter", "outline"), ("deformer", "roi_metric"),
                 ("deformer", "acceleration"), ("renderer", "pairing"), ("renderer", "inpaint")}


class Plain(Node):
    """A user's node with plain defaults (no description, no range)."""

    NAME = "plain"
    PARAMS = {"gain": 1.5, "label": "x", "on": True}


class Declared(Node):
    NAME = "declared"
    PARAMS = {"iterations": Param(5, "iterations per frame", range=(1, 50)),
              "mode": Param("ray", "how", choices=("ray", "nearest")),
              "rate": Param(0.5, "a rate, Hz", range=(0.0, None))}


@pytest.mark.parametrize("name", sorted(BUILTIN_NODES))
def test_every_builtin_parameter_is_described_with_a_range_or_choices(name):
    cls = load_node_class(name, BUILTIN_NODES)
    for key, param in declared(cls.PARAMS).items():
        assert param.description, f"{name}.{key} has no description"
        if isinstance(param.default, (int, float)) and not isinstance(param.default, bool):
            assert param.range is not None, f"{name}.{key} is numeric but declares no range"
        if (name, key) in CHOICE_PARAMS:
            assert param.choices and param.default in param.choices, f"{name}.{key} declares no choices"
        assert not param.problem(param.default)


def test_joystick_and_deformer_share_the_axes_parameters_of_the_geometry_module():
    joystick = load_node_class("joystick", BUILTIN_NODES).PARAMS
    deformer = load_node_class("deformer", BUILTIN_NODES).PARAMS
    for speed, deadzone in ((joystick["speed_mm_s"], joystick["deadzone"]),
                            (deformer["joystick_speed"], deformer["joystick_deadzone"])):
        assert (speed.default, speed.range) == (SPEED_MM_S, SPEED_MM_S_RANGE)
        assert (deadzone.default, deadzone.range) == (DEADZONE, DEADZONE_RANGE)


def test_values_are_converted_and_checked():
    assert resolve_params("declared", Declared.PARAMS, {"iterations": "7", "rate": 3}) == {
        "iterations": 7, "mode": "ray", "rate": 3.0}
    with pytest.raises(ParameterError) as err:
        resolve_params("fitter", Declared.PARAMS, {"iterations": "0"})
    assert str(err.value) == "fitter.iterations=0 is out of range [1, 50]"
    with pytest.raises(ParameterError, match=r"^declared.mode='sideways' is not one of ray, nearest$"):
        Declared(params={"mode": "sideways"})
    with pytest.raises(ParameterError, match=r"declared.rate=-1.0 is out of range \[0.0, inf\)"):
        Declared(params={"rate": -1})
    with pytest.raises(ParameterError, match="unknown param"):
        Declared(params={"colour": "red"})
    with pytest.raises(ValueError, match="out of range"):
        Param(0, "a default outside its own range", range=(1, 5))
    with pytest.raises(ValueError, match="not both"):
        Param(1, "x", range=(0, 2), choices=(1, 2))


def test_an_unquoted_on_or_off_in_yaml_is_the_string_choice():
    """YAML 1.1 reads `plate: off` as False: a string parameter takes it back as "off"."""
    import yaml

    from facesculpt.nodes.renderer.node import RendererNode

    given = yaml.safe_load("{plate: off, mouth: off, atlas: on}")
    assert given == {"plate": False, "mouth": False, "atlas": True}
    values = resolve_params("renderer", RendererNode.PARAMS, given)
    assert (values["plate"], values["mouth"], values["atlas"]) == ("off", "off", "on")
    with pytest.raises(ParameterError, match="is not one of off, paint"):
        resolve_params("renderer", RendererNode.PARAMS, {"mouth": True})  # "on" is not a choice of mouth


def test_plain_defaults_keep_working():
    node_values = resolve_params("plain", Plain.PARAMS, {"gain": "2", "on": "false"})
    assert node_values == {"gain": 2.0, "label": "x", "on": False}
    assert Plain.default_params() == {"gain": 1.5, "label": "x", "on": True}
    assert "  gain   float, default 1.5\n" in params_help(Plain) + "\n"
    text = params_help(Declared)
    assert "iterations  int, default 5, range [1, 50]: iterations per frame" in text
    assert "mode        str, default 'ray', one of ray, nearest: how" in text


def _run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", *args], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=timeout)


def test_help_lists_every_parameter_with_its_description_and_range():
    out = _run("run", "deformer", "--help")
    assert out.returncode == 0, out.stderr
    cls = load_node_class("deformer", BUILTIN_NODES)
    for key, param in declared(cls.PARAMS).items():
        line = next((x for x in out.stdout.splitlines() if x.split()[:1] == [key]), None)
        assert line is not None, f"{key} is not listed"
        assert param.description in line and repr(param.default) in line
        assert (param.range_text() if param.range else ", ".join(param.choices or ())) in line
    assert "one of geodesic, euclidean" in out.stdout and "range [1, 100]" in out.stdout


@pytest.mark.slow
def test_a_bad_value_stops_a_real_node_in_one_sentence_with_exit_code_2():
    out = _run("run", "deformer", "iterations=0")
    assert out.returncode == EXIT_BAD_PARAMETER == 2
    assert out.stderr.strip().splitlines() == ["facesculpt: deformer.iterations=0 is out of range [1, 100]"]
    out = _run("run", "renderer", "inpaint=navier")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == ["facesculpt: renderer.inpaint='navier' is not one of pushpull, telea, ns, patch, drag"]
    out = _run("run", "camera", "fps=fast")
    assert out.returncode == 2 and "camera.fps" in out.stderr and "Traceback" not in out.stderr


@pytest.mark.slow
def test_the_launcher_does_not_respawn_a_node_that_exited_2(graph, tmp_path):
    """Both nodes are marked respawn: the one that crashes (exit 1) comes back, the one whose
    parameter names what cannot be used (exit 2: a missing video; a value out of range is refused
    before the graph starts, test_launch_check) does not, and says so once."""
    (tmp_path / "crasher.py").write_text("from facesculpt.runtime import Node\n\n\nclass Crasher(Node):\n"
                                         "    def setup(self):\n        raise RuntimeError('crash')\n")
    launch = tmp_path / "graph.yaml"
    launch.write_text(yaml.safe_dump({"nodes": [
        {"name": "bad_param", "node": "camera", "respawn": True, "params": {"source": str(tmp_path / "missing.mp4")}},
        {"name": "bad_file", "node": f"{tmp_path / 'crasher.py'}:Crasher", "respawn": True, "respawn_delay_s": 0.1},
    ]}))
    log = tmp_path / "launch.txt"
    with open(log, "w") as f:
        proc = graph.spawn("launch", str(launch), stdout=f, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while log.read_text().count("[bad_file] died") < 3 and time.monotonic() < deadline:
        time.sleep(0.2)
    text = log.read_text()
    assert text.count("[bad_file] died") >= 3, text
    assert "[bad_param] died" not in text and text.count("[bad_param] running (pid") == 1
    assert text.count("[bad_param] ended (exit code 2)") == 1 and "not respawning" in text
    assert text.count(f"facesculpt: camera: video file {tmp_path / 'missing.mp4'} not found") == 1
    assert proc.poll() is None  # the rest of the graph goes on
