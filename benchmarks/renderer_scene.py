"""Real frames with a face model placed on them, for the renderer's tests and benchmark.

Two ways to put a model on the face of a real video frame:

* :func:`place_fitted` — the real pipeline: landmark detector + fitter (needs the networks
  from `facesculpt setup`); orthographic, as the fitter's default;
* :func:`place_marked` — a perspective pose (cv2.solvePnP, f = frame width) of the model's
  mean from eight hand-marked pixel positions of named landmarks on frame 0 (eye corners,
  nose tip, mouth corners, chin); needs no networks.

The edit is the issue's: nose tip pulled out 15 mm, both cheeks pushed in 8 mm, solved by
the deformer's ARAP edit stack and merged by its Eq. 5.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

LANDMARKS = ("right_eye_outer", "right_eye_inner", "left_eye_inner", "left_eye_outer",
             "nose_tip", "mouth_right", "mouth_left", "chin")

# Frame 0 of each video, at the given size: pixel positions of LANDMARKS, marked by hand.
FRAMES = {
    "s18": {"size": (856, 480), "points": [(478, 144), (508, 143), (548, 138), (582, 133),
                                           (540, 188), (512, 218), (560, 216), (532, 262)]},
    "d0": {"size": (512, 512), "points": [(190, 248), (228, 250), (285, 250), (318, 248),
                                          (255, 310), (220, 372), (292, 372), (257, 432)]},
}


def read_frames(data_dir: Path, name: str, count: int = 1, start: int = 0,
                size: tuple[int, int] | None = None) -> list[np.ndarray]:
    """``count`` consecutive BGR frames of the shared video ``name`` from ``start``, at ``size``
    (W, H) (default FRAMES[name]["size"]; the video's own size for videos not listed there), for
    the tests and the benchmarks."""
    cap = cv2.VideoCapture(str(Path(data_dir) / "video" / f"{name}.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, start)
    frames = []
    size = size or FRAMES.get(name, {}).get("size")
    while len(frames) < count:
        ok, frame = cap.read()
        if not ok:
            break
        if size is not None and (frame.shape[1], frame.shape[0]) != size:
            frame = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
        frames.append(frame)
    cap.release()
    assert len(frames) == count, f"{name}.mp4 has fewer than {start + count} frames"
    return frames


@dataclass
class Placement:
    """A model posed on a frame: what a FaceState carries, plus the shape the edit acts on."""

    fitted: np.ndarray       # (V, 3) camera space (mm, perspective; px, orthographic)
    projected: np.ndarray    # (V, 2) pixels
    R: np.ndarray            # (3, 3) model -> camera rotation
    scale: float             # model mm -> camera units (1 for perspective)
    rest: np.ndarray         # (V, 3) model space, mm: the neutral the edit deforms
    triangles: np.ndarray    # (T, 3)
    landmarks: dict          # landmark name -> vertex
    K: np.ndarray | None     # (3, 3) under perspective, None under orthographic

    def project(self, vertices: np.ndarray) -> np.ndarray:
        v = np.asarray(vertices, np.float64)
        if self.K is None:  # the fitter's orthographic camera space: x, y are pixels
            return v[:, :2].copy()
        p = v @ self.K.T
        return p[:, :2] / p[:, 2:]


def place_marked(model, name: str) -> Placement:
    """The model's mean posed on frame 0 of video ``name`` by a perspective pose (f = frame
    width) from the hand-marked landmark positions (needs no networks)."""
    W, H = FRAMES[name]["size"]
    K = np.array([[W, 0, W / 2], [0, W, H / 2], [0, 0, 1.0]])
    index = {str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)}
    mean = np.asarray(model.mean, np.float64)
    obj = mean[[index[n] for n in LANDMARKS]]
    ok, rvec, tvec = cv2.solvePnP(obj, np.array(FRAMES[name]["points"], np.float64), K, None,
                                  flags=cv2.SOLVEPNP_SQPNP)
    assert ok
    R = cv2.Rodrigues(rvec)[0]
    fitted = mean @ R.T + tvec.ravel()
    p = Placement(fitted, np.zeros((len(mean), 2)), R, 1.0, mean, np.asarray(model.triangles), index, K)
    p.projected = p.project(fitted)
    return p


def place_fitted(model, frame: np.ndarray, detector) -> Placement:
    """The model fitted to ``frame`` by the real pipeline: the landmark detector (468 points;
    their iBUG-68 subset for a sparse model) and the fitter (orthographic by default)."""
    from facesculpt.geometry import to_ibug68
    from facesculpt.nodes.fitter import FitterConfig, make_fitter

    faces = detector.detect(frame)
    assert faces, "no face detected in the frame"
    points = faces[0].points
    fitter = make_fitter(model, FitterConfig(), (frame.shape[1], frame.shape[0]))
    r = fitter.fit(points if model.dense else to_ibug68(points))
    index = {str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)}
    K = None if r.projection == "orthographic" else np.asarray(r.K, np.float64)
    return Placement(np.asarray(r.vertices, np.float64), np.asarray(r.projected, np.float64),
                     np.asarray(r.R, np.float64), float(r.scale), np.asarray(r.model_vertices, np.float64),
                     np.asarray(model.triangles), index, K)


def cheek_rim(scene: Placement, half_height_mm: float = 6.0, depth_mm: float = 6.0) -> list[int]:
    """The vertices of the side of the face at the height of the cheek landmarks: on each side,
    those within ``half_height_mm`` of the landmark's height and ``depth_mm`` of the widest
    |x| there. In a frontal view they form the face's outline."""
    index = scene.landmarks
    mean = scene.rest
    rim = []
    for name in ("right_cheek", "left_cheek"):
        cheek = mean[index[name]]
        band = np.flatnonzero((np.abs(mean[:, 1] - cheek[1]) < half_height_mm)
                              & (np.sign(mean[:, 0]) == np.sign(cheek[0])))
        widest = np.abs(mean[band, 0]).max()
        rim += band[np.abs(mean[band, 0]) > widest - depth_mm].tolist()
    return rim


def issue_edit(scene: Placement, nose_mm: float = 15.0, cheeks_mm: float = 8.0) -> np.ndarray:
    """(V, 3) model-space displacement (mm): nose tip pulled out along +z by ``nose_mm``; both
    cheeks pushed in by ``cheeks_mm`` toward the midline at the face's side (the cheek rim,
    so the outline narrows and uncovers background); solved by the deformer's ARAP edit stack."""
    from facesculpt.nodes.deformer import EditStack

    stack = EditStack(scene.rest, scene.triangles, list(scene.landmarks), list(scene.landmarks.values()))
    nose = stack.landmark_vertex("nose_tip")
    stack.begin([nose])
    stack.set_offset(nose, [0.0, 0.0, nose_mm])
    rim = cheek_rim(scene)
    stack.begin(rim, roi_radius=40.0)
    for v in rim:
        stack.set_offset(v, [-np.sign(scene.rest[v, 0]) * cheeks_mm, 0.0, 0.0])
    return stack.solve()


def rasterize_region(px: np.ndarray, triangles: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the filled silhouette of a mesh projected to ``px`` (V, 2), drawn with
    OpenCV (independent of the renderer's OpenGL path): every triangle, then the holes of
    the outline filled."""
    mask = np.zeros(shape, np.uint8)
    pts = np.round(np.asarray(px) * 16).astype(np.int32)
    for tri in np.asarray(triangles):
        cv2.fillConvexPoly(mask, pts[tri], 1, lineType=cv2.LINE_8, shift=4)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(mask, contours, -1, 1, -1)
    return mask.astype(bool)


def dilate(mask: np.ndarray, px: int) -> np.ndarray:
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    return cv2.dilate(mask.astype(np.uint8), k).astype(bool)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def plane_mesh(centre, side: float, n: int = 12):
    """A square grid mesh ``side`` px wide around ``centre`` (x, y) in the fitter's orthographic
    camera space (x, y in pixels), bulged slightly in depth so that the camera is determined:
    (vertices (n*n, 3), pixels (n*n, 2), triangles)."""
    u = np.linspace(-side / 2, side / 2, n)
    x, y = np.meshgrid(u + centre[0], u + centre[1])
    r2 = (x - centre[0]) ** 2 + (y - centre[1]) ** 2
    vertices = np.column_stack([x.ravel(), y.ravel(), 0.002 * r2.ravel()])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return vertices, vertices[:, :2].copy(), triangles
