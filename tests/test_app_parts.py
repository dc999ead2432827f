"""The offline engine's small parts, in-process and fast (the fast tier's share of modules that
the end-to-end tests otherwise reach only in subprocesses): batch planning, the parameters
export, the bench's scenario and competing load, the node base's old import path."""

from __future__ import annotations

import csv
import importlib
import json
import os
import warnings
from argparse import Namespace

import numpy as np
import pytest

from facesculpt.app.batch import expand_inputs, is_batch, plan_jobs
from facesculpt.app.bench_scenario import DRAGS_S, LOAD_AT_S, BenchScenario
from facesculpt.app.busy_load import competing_load
from facesculpt.app.params_export import COLUMNS, ParamsExport
from facesculpt.nodes.fitter.expression import NAMES
from facesculpt.nodes.fitter.result import FitResult


def _videos(folder, *names):
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_bytes(b"x")
    return folder


def test_a_batch_expands_folders_and_globs_once_each_in_order(tmp_path):
    folder = _videos(tmp_path / "in", "b.mp4", "a.mov", "notes.txt")
    found = expand_inputs([str(folder), str(folder / "*.mp4")])
    assert [p.name for p in found] == ["a.mov", "b.mp4"]
    with pytest.raises(FileNotFoundError, match="no such file"):
        expand_inputs([str(tmp_path / "missing.mp4")])
    with pytest.raises(ValueError, match="holds no video"):
        expand_inputs([str(_videos(tmp_path / "empty", "readme.md"))])


def test_a_batch_names_each_output_after_its_input_and_refuses_a_clash(tmp_path):
    jobs = plan_jobs([tmp_path / "x" / "a.mp4", tmp_path / "b.mov"], tmp_path / "out", "mkv")
    assert [(i.name, o.name) for i, o in jobs] == [("a.mp4", "a.mkv"), ("b.mov", "b.mkv")]
    with pytest.raises(ValueError, match="would both be written"):
        plan_jobs([tmp_path / "x" / "a.mp4", tmp_path / "y" / "a.mov"], tmp_path / "out", ".mp4")


def test_what_makes_a_batch(tmp_path):
    one = Namespace(input=["a.mp4"], output="out.mp4", cluster="", workers=0)
    assert not is_batch(one)
    assert is_batch(Namespace(**{**vars(one), "input": ["a.mp4", "b.mp4"]}))
    assert is_batch(Namespace(**{**vars(one), "output": str(tmp_path) + os.sep}))
    assert is_batch(Namespace(**{**vars(one), "workers": 2}))


def _fit(yaw_deg: float, t, expression) -> FitResult:
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    v = np.zeros((3, 3), np.float32)
    fit = FitResult(vertices=v, projected=np.zeros((3, 2), np.float32), R=R, t=np.asarray(t, np.float64), scale=1.0,
                    alpha=np.zeros(0), beta=np.zeros(0), residual_px=0.0, projection="perspective", K=None,
                    model_vertices=v)
    fit.expression = np.asarray(expression, np.float64)
    return fit


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_the_parameters_export_writes_a_row_per_face_and_an_empty_row_without_one(tmp_path, suffix):
    path = tmp_path / f"params{suffix}"
    export = ParamsExport(path)
    fit = _fit(20.0, (1.0, 2.0, 500.0), np.linspace(-1, 1, len(NAMES)))
    export.add(0, 0.0, {0: fit})
    export.add(1, 0.04, {})
    assert export.write() == path and not list(tmp_path.glob(".*writing"))
    if suffix == ".csv":
        rows = list(csv.DictReader(path.open()))
        assert list(rows[0]) == list(COLUMNS)
        first, second = rows
    else:
        doc = json.loads(path.read_text())
        assert doc["columns"] == list(COLUMNS)
        first, second = doc["rows"]
    yaw, pitch, roll = fit.yaw_pitch_roll
    assert abs(float(first["yaw_deg"]) - yaw) < 1e-3 and abs(float(first["roll_deg"]) - roll) < 1e-3
    assert float(first["tx_mm"]) == 1.0 and float(first["tz_mm"]) == 500.0
    assert float(first[NAMES[0]]) == -1.0 and float(first[NAMES[-1]]) == 1.0
    assert second["face"] in ("", None) and second["yaw_deg"] in ("", None)


def test_the_parameters_export_refuses_another_format(tmp_path):
    with pytest.raises(ValueError, match="write a .csv or a .json"):
        ParamsExport(tmp_path / "params.xlsx")


def test_the_bench_scenario_gives_each_event_once_in_time_order():
    scenario = BenchScenario("nose_longer.json")
    early = scenario.due(DRAGS_S[0][0] - 0.5)
    assert [e.kind for e in early] == ["command"] and early[0].argument == "nose_longer.json"
    during = scenario.due(DRAGS_S[0][1])
    assert during[0].kind == "press" and during[-1].kind == "release"
    assert {e.kind for e in during[1:-1]} == {"move"}
    rest = scenario.due(1e9)
    assert scenario.due(1e9) == []
    loads = [e for e in early + during + rest if e.kind == "command" and e.command == "load_preset"]
    assert len(loads) == len(LOAD_AT_S)


def test_the_competing_load_runs_busy_processes_and_ends_them():
    with competing_load(2) as pids:
        assert len(pids) == 2
        for pid in pids:
            os.kill(pid, 0)  # alive
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def test_the_node_bases_old_import_path_warns_and_still_works():
    import facesculpt.node as old

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        importlib.reload(old)
    from facesculpt.runtime import Node

    assert old.Node is Node
    assert any(issubclass(w.category, DeprecationWarning) for w in caught)
