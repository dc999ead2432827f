"""The eos importer and the .npz model format, checked on the shared Surrey Face Model and
cross-checked against eos-py (the reference reader) where installed."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from facesculpt.nodes.fitter import eos_reader
from facesculpt.nodes.fitter.eos_import import import_eos, sfm_files
from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel, save_model
from facesculpt.nodes.fitter.model_loading import load_model


@pytest.fixture(scope="module")
def sfm(data_dir):
    return import_eos(**sfm_files(data_dir))


def test_sfm_import_has_the_papers_sizes(sfm):
    assert sfm.num_vertices == 3448
    assert sfm.triangles.shape == (6736, 3)
    assert sfm.num_shape == 63
    assert sfm.num_expression == 6 and sfm.expression_kind == "blendshapes"
    assert sfm.expression_names == ["anger", "disgust", "fear", "happiness", "sadness", "surprise"]
    assert sfm.texcoords.shape == (3448, 2)
    assert len(sfm.outline_right) == 17 and len(sfm.outline_left) == 17
    assert sfm.outline_landmarks_right == [str(i) for i in range(1, 9)]
    assert sfm.outline_landmarks_left == [str(i) for i in range(10, 18)]
    idx = sfm.landmark_index()
    assert idx["31"] == 114 and idx["9"] == 33 and "1" not in idx and "61" not in idx
    # Model space is mm, x toward the subject's left: the left outline lies at +x, the right at -x.
    assert sfm.mean[sfm.outline_left, 0].min() > 0 > sfm.mean[sfm.outline_right, 0].max()
    eyes = np.linalg.norm(sfm.mean[idx["left_eye_outer"]] - sfm.mean[idx["right_eye_outer"]])
    assert 80 < eyes < 105


def test_sfm_semantic_landmarks_are_where_their_names_say(sfm):
    idx = sfm.landmark_index()
    p = {k: sfm.mean[v] for k, v in idx.items()}
    assert p["forehead"][1] > p["left_brow"][1] > p["left_eye_outer"][1] > p["nose_tip"][1] > p["chin"][1]
    assert p["left_cheek"][0] > 15 and p["right_cheek"][0] < -15
    assert p["mouth_right"][1] < p["left_cheek"][1] < p["left_eye_outer"][1]
    assert abs(p["forehead"][0]) < 5


def test_import_is_identical_to_eos_py(sfm, data_dir):
    eos = pytest.importorskip("eos")
    files = sfm_files(data_dir)
    ref = eos.morphablemodel.load_model(str(files["shape_bin"]))
    shape = ref.get_shape_model()
    np.testing.assert_array_equal(sfm.mean.reshape(-1), shape.get_mean())
    np.testing.assert_array_equal(sfm.shape_basis.reshape(3 * 3448, 63), shape.get_orthonormal_pca_basis())
    raw = eos_reader.read_morphable_model(files["shape_bin"])
    np.testing.assert_array_equal(raw.shape.eigenvalues, shape.get_eigenvalues())
    np.testing.assert_allclose(sfm.shape_std, np.sqrt(shape.get_eigenvalues()), rtol=1e-6)
    np.testing.assert_array_equal(sfm.triangles, np.asarray(shape.get_triangle_list()))
    np.testing.assert_array_equal(raw.texcoords, np.asarray(ref.get_texture_coordinates()))
    np.testing.assert_array_equal(sfm.texcoords, np.asarray(ref.get_texture_coordinates(), np.float32))
    blend = eos.morphablemodel.load_blendshapes(str(files["blendshapes"]))
    assert [b.name for b in blend] == sfm.expression_names
    for i, b in enumerate(blend):
        np.testing.assert_array_equal(sfm.expression_basis[:, :, i].reshape(-1), b.deformation)
    # The sample eos draws for the same coefficients equals ours.
    alpha = np.linspace(-1.5, 1.5, 63).astype(np.float32)
    ref_sample = np.asarray(shape.draw_sample(alpha.tolist())).reshape(-1, 3)
    np.testing.assert_allclose(sfm.instance(alpha), ref_sample, atol=1e-3)


def test_reader_handles_newer_eos_versions_written_by_eos_py(tmp_path, data_dir):
    """eos-py writes class version 4 (expression model + landmark definitions + texture triangles);
    our reader must read what it wrote, blendshape and PCA expression variants alike."""
    eos = pytest.importorskip("eos")
    mm = eos.morphablemodel
    files = sfm_files(data_dir)
    ref = mm.load_model(str(files["shape_bin"]))
    shape = ref.get_shape_model()
    blend = mm.load_blendshapes(str(files["blendshapes"]))
    texcoords = [list(map(float, t)) for t in ref.get_texture_coordinates()]
    tris = shape.get_triangle_list()
    defs = {"nose_tip": 114, "chin": 33}
    with_blend = mm.MorphableModel(shape, blend, mm.PcaModel(), defs, texcoords, tris)
    mm.save_model(with_blend, str(tmp_path / "v4_blend.bin"))
    got = eos_reader.read_morphable_model(tmp_path / "v4_blend.bin")
    assert got.version == 4
    assert got.landmark_definitions == defs
    assert [b.name for b in got.expression] == [b.name for b in blend]
    np.testing.assert_array_equal(got.expression[3].deformation, blend[3].deformation)
    np.testing.assert_array_equal(got.texture_triangles, np.asarray(tris))
    np.testing.assert_array_equal(got.shape.basis, shape.get_orthonormal_pca_basis())

    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(3 * 3448, 4)))[0].astype(np.float32)
    expr_pca = mm.PcaModel(np.zeros(3 * 3448, np.float32), basis, np.array([4.0, 3.0, 2.0, 1.0], np.float32), tris)
    with_pca = mm.MorphableModel(shape, expr_pca, mm.PcaModel(), None, texcoords, [])
    mm.save_model(with_pca, str(tmp_path / "v4_pca.bin"))
    model = import_eos(tmp_path / "v4_pca.bin")
    assert model.expression_kind == "pca" and model.num_expression == 4
    np.testing.assert_allclose(model.expression_std, [2.0, np.sqrt(3.0), np.sqrt(2.0), 1.0], rtol=1e-6)
    np.testing.assert_array_equal(model.expression_basis.reshape(-1, 4), basis)


def test_npz_round_trip_keeps_every_field(sfm, tmp_path):
    path = save_model(sfm, tmp_path / "sfm.npz")
    back = load_model(path)
    for name in ("mean", "triangles", "shape_basis", "shape_std", "expression_basis", "expression_std",
                 "expression_lower", "expression_upper", "texcoords", "landmark_vertices",
                 "outline_right", "outline_left"):
        np.testing.assert_array_equal(getattr(back, name), getattr(sfm, name), err_msg=name)
    for name in ("model_id", "expression_kind", "expression_names", "landmark_names", "units",
                 "outline_landmarks_right", "outline_landmarks_left", "dense"):
        assert getattr(back, name) == getattr(sfm, name), name
    # Saved without pickles: numpy refuses pickled objects by default and must still load it.
    with np.load(path, allow_pickle=False) as data:
        assert str(data["format"]) == "facesculpt-morphable-model"


def test_import_eos_command_writes_a_loadable_model(data_dir, tmp_path):
    files = sfm_files(data_dir)
    out = tmp_path / "model.npz"
    argv = ["model", "import-eos", str(files["shape_bin"]), "--blendshapes", str(files["blendshapes"]),
            "--landmarks", str(files["landmarks"]), "--contours", str(files["contours"]), "-o", str(out)]
    from facesculpt.cli import main

    rc = main(argv)
    assert rc == 0
    model = load_model(out)
    assert (model.num_vertices, model.num_shape, model.num_expression) == (3448, 63, 6)


def test_truncated_eos_file_is_refused_with_the_place(data_dir, tmp_path):
    raw = sfm_files(data_dir)["shape_bin"].read_bytes()
    bad = tmp_path / "cut.bin"
    bad.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(eos_reader.EosFormatError, match="truncated while reading shape model basis"):
        eos_reader.read_morphable_model(bad)
    blend = tmp_path / "not_a_model.bin"
    blend.write_bytes(sfm_files(data_dir)["blendshapes"].read_bytes())
    with pytest.raises(eos_reader.EosFormatError, match="version"):
        eos_reader.read_morphable_model(blend)
    junk = tmp_path / "junk.bin"
    junk.write_bytes(struct.pack("<I", 1) + struct.pack("<ii", 9, 1) + b"\0" * 36 + b"\1\2")
    with pytest.raises(eos_reader.EosFormatError):
        eos_reader.read_morphable_model(junk)


def test_model_validation_names_the_bad_field(tmp_path):
    tri = np.array([[0, 1, 2]], np.int32)
    mean = np.eye(3, dtype=np.float32)
    with pytest.raises(ModelFormatError, match=r"mean must be \(V, 3\)"):
        MorphableModel("x", mean[:, :2], tri)
    with pytest.raises(ModelFormatError, match="triangles index vertices"):
        MorphableModel("x", mean, tri + 1)
    with pytest.raises(ModelFormatError, match="shape_std has 1 values"):
        MorphableModel("x", mean, tri, shape_basis=np.zeros((3, 3, 2)), shape_std=np.ones(1))
    with pytest.raises(ModelFormatError, match="landmark_vertices must index"):
        MorphableModel("x", mean, tri, landmark_names=["a"], landmark_vertices=[7])
    with pytest.raises(ModelFormatError, match="NaN"):
        MorphableModel("x", np.full((3, 3), np.nan), tri)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ModelFormatError, match="missing format"):
        load_model(tmp_path / "other.npz")
    with pytest.raises(FileNotFoundError, match="import-eos"):
        load_model(tmp_path / "nope.npz")
