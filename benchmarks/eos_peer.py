"""eos-py's fitter as the reference the fitter is measured against (tests and benchmarks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


class EosPeer:
    """eos-py's ``fit_shape_and_pose`` on the same model files, as the reference for tests and
    benchmarks (eos-py is a test extra; imported only here). ``files``:
    :func:`facesculpt.nodes.fitter.eos_import.sfm_files`."""

    def __init__(self, files: dict, image_size: tuple[int, int] = (640, 480), iterations: int = 5):
        import eos

        self.eos = eos
        mm = eos.morphablemodel
        base = mm.load_model(str(files["shape_bin"]))
        blend = mm.load_blendshapes(str(files["blendshapes"]))
        self.model = mm.MorphableModel(base.get_shape_model(), blend, color_model=mm.PcaModel(),
                                       vertex_definitions=None, texture_coordinates=base.get_texture_coordinates())
        self.mapper = eos.core.LandmarkMapper(str(files["landmarks"]))
        sfm_dir = Path(files["shape_bin"]).parent
        self.edges = mm.load_edge_topology(str(sfm_dir / "sfm_3448_edge_topology.json"))
        self.contour_landmarks = eos.fitting.ContourLandmarks.load(str(files["landmarks"]))
        self.model_contour = eos.fitting.ModelContour.load(str(files["contours"]))
        self.image_size = image_size
        self.iterations = iterations

    def fit(self, points: np.ndarray, ids: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Fitted mesh (V, 3) in model space and its projection (V, 2) in pixels."""
        eos = self.eos
        lms = [eos.core.Landmark(k, [float(p[0]), float(p[1])]) for k, p in zip(ids, points) if np.isfinite(p).all()]
        W, H = self.image_size
        mesh, params, _, _ = eos.fitting.fit_shape_and_pose(
            self.model, lms, self.mapper, W, H, self.edges, self.contour_landmarks, self.model_contour, self.iterations
        )
        V = np.asarray(mesh.vertices, np.float64)
        P = eos.fitting.get_3x4_affine_camera_matrix(params, W, H)
        return V, (np.c_[V, np.ones(len(V))] @ np.asarray(P).T)[:, :2]
