"""`facesculpt model calibrate` (facesculpt/app/landmark_calibration.py, issue 46): the landmark
calibration built from renders of the model's own synthetic head, kept with the model, read by
``load_model`` by default; bad input gets one sentence and overwrites nothing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.app import landmark_calibration as lc
from facesculpt.cli import main
from facesculpt.nodes.fitter.calibration import calibration_file, project_model, uncalibrated
from facesculpt.nodes.fitter.model import save_model
from facesculpt.nodes.fitter.model_loading import load_model


@pytest.fixture(scope="module")
def sfm_file(data_dir, tmp_path_factory):
    """The Surrey model, uncalibrated, as a .npz model file."""
    path = tmp_path_factory.mktemp("model") / "sfm.npz"
    save_model(uncalibrated(load_model("sfm")), path)
    return path


@pytest.fixture(scope="module")
def photo(data_dir, tmp_path_factory):
    """A texture photo: a frame of another person than the realism benchmark's (d3)."""
    path = tmp_path_factory.mktemp("photo") / "d3_10.png"
    cv2.imwrite(str(path), lc.video_frame(data_dir / "video" / "d3.mp4", 10))
    return path


def _one_sentence(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err, "no message"
    assert err[-1].startswith("facesculpt model calibrate: ")
    return err[-1]


def test_bad_input_gets_one_sentence_and_overwrites_nothing(sfm_file, photo, tmp_path, capsys):
    assert main(["model", "calibrate", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "x.npz")]) == 2
    assert "missing.npz" in _one_sentence(capsys)
    assert main(["model", "calibrate", str(sfm_file), "--textures", str(photo)]) == 2
    assert "-o OUTPUT" in _one_sentence(capsys)
    kept = tmp_path / "kept.npz"
    kept.write_bytes(b"the user's file")
    assert main(["model", "calibrate", str(sfm_file), "--textures", str(photo), "-o", str(kept)]) == 2
    assert "not overwritten" in _one_sentence(capsys)
    assert kept.read_bytes() == b"the user's file"
    not_a_photo = tmp_path / "notes.png"
    not_a_photo.write_text("not an image")
    assert main(["model", "calibrate", str(sfm_file), "--textures", str(not_a_photo), "-o",
                 str(tmp_path / "out.npz")]) == 2
    assert "cannot read the texture photo" in _one_sentence(capsys)
    assert not (tmp_path / "out.npz").exists()
    assert main(["model", "calibrate", "facemesh", "-o", str(tmp_path / "fm.npz")]) == 2
    assert "dense" in _one_sentence(capsys)


@pytest.mark.slow
def test_the_learned_points_explain_the_network_and_load_model_uses_them(data_dir, photo, tmp_path, monkeypatch):
    model = uncalibrated(load_model("sfm"))
    seqs = lc.sequences(model, [cv2.imread(str(photo))], frames=8, workers=1)
    calibrated, learned = lc.learn(model, seqs, "d3 frame 10")
    s = seqs[0]
    assert np.isfinite(s["observed"]).all(), "the network lost the synthetic head"
    before = np.linalg.norm(s["observed"] - project_model(s["K"], s["R"], s["c"], s["vertices"]), axis=2)
    after = np.linalg.norm(s["observed"] - project_model(s["K"], s["R"], s["c"], s["vertices"] + learned["offsets"]),
                           axis=2)
    assert after.mean() < 0.7 * before.mean(), (before.mean(), after.mean())
    assert 0.5 < np.linalg.norm(learned["offsets"], axis=1).mean() < 15.0   # mm: millimetres, not centimetres
    assert "d3 frame 10" in calibrated.calibration and "identity seed 101" in calibrated.calibration
    assert np.isfinite(calibrated.landmark_weights).all() and calibrated.landmark_weights.min() > 0
    # 'sfm' built on the fly reads its calibration from the models folder, when it is there
    monkeypatch.setenv("FACESCULPT_HOME", str(tmp_path / "home"))
    assert load_model("sfm").calibration == ""
    lc.save_builtin(calibrated, calibration_file(model.model_id))
    again = load_model("sfm")
    assert again.calibration == calibrated.calibration
    np.testing.assert_allclose(again.landmark_offsets, calibrated.landmark_offsets)
    # a .npz model keeps its calibration in its own file
    save_model(calibrated, tmp_path / "sfm_calibrated.npz")
    assert load_model(tmp_path / "sfm_calibrated.npz").calibration == calibrated.calibration
