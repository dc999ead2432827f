"""The custom-input recipe: examples/custom_input_node.py, started by hand next to a launched
graph, moves the face (its events reach the deformer and change face/deformation)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from test_input_script import sfm, sfm_model_msg, sfm_state_msg  # noqa: F401  (sfm is a fixture)

from facesculpt.msgs import Deformation, FaceModel, FaceState
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE, LATCHED


@pytest.mark.slow
def test_example_custom_node_joins_a_launched_graph_and_moves_the_nose(graph, sfm, tmp_path):  # noqa: F811
    launch = tmp_path / "graph.yaml"
    launch.write_text(yaml.safe_dump({"nodes": [{"name": "deformer", "node": "deformer",
                                                 "params": {"round_s": 0.02}}]}))
    graph.spawn("launch", str(launch))
    face = Node(name="custom_test_face")  # stands in for the camera, landmarks and fitter
    model_pub = face.advertise("face/model", FaceModel, qos=LATCHED)
    state_pub = face.advertise("face/state", FaceState)
    face.timer(0.1, lambda: state_pub.publish(sfm_state_msg(sfm, stamp=1)))
    got: list[Deformation] = []
    face.subscribe("face/deformation", Deformation, got.append, qos=EVERY_MESSAGE)
    graph.node(face)
    model_pub.publish(sfm_model_msg(sfm))
    assert graph.spin_until(face, lambda: bool(got), 20), "the launched deformer is not answering"
    assert not np.any(got[-1].displacement)

    user = subprocess.Popen([sys.executable, str(REPO_ROOT / "examples" / "custom_input_node.py"),
                             "amplitude_mm=8", "period_s=1.0"], env=graph.env)
    graph.procs.append(user)
    nose = sfm.landmark_index()["nose_tip"]
    got.clear()
    xs = lambda: [float(d.displacement[nose][0]) for d in got]  # noqa: E731
    assert graph.spin_until(face, lambda: got and max(xs()) > 6.0 and min(xs()) < -6.0, 20), \
        f"the nose went {min(xs(), default=0):.1f}..{max(xs(), default=0):.1f} mm along x"
    last = got[-1]
    assert list(last.handles) == [nose]
    assert max(xs()) <= 8.0 + 1e-3 and min(xs()) >= -8.0 - 1e-3  # within the wiggle's amplitude
    assert np.allclose(last.displacement[nose][1:], 0.0, atol=1e-4)  # along model x only
    assert user.poll() is None
