"""A 3D active appearance model's texture part (seed 004): how faces look, per model vertex.

Each training face, fitted by its landmarks, is sampled at its projected vertices where it faces
the camera (:func:`vertex_appearance`: grey levels, normalised to zero mean and unit spread over
the face, so the lighting's gain and bias are not learned); :func:`train_appearance` keeps their
mean and leading principal components (PCA with the unseen vertices filled in from the
components, a few rounds). :func:`.fit_image.fit_image` aligns a model to a photo with it.

Arrays in, arrays out; :meth:`AppearanceModel.save` / :meth:`AppearanceModel.load` keep one as
``.npz`` (``facesculpt model train-appearance`` writes one from the shared photos).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesculpt.geometry.vertex_normals import vertex_normals

from .appearance import MIN_FRONTALITY, frontality, sample

#: Rounds of filling the unseen vertices from the components.
FILL_ROUNDS = 10


@dataclass
class AppearanceModel:
    """mean (V,), components (V, k) orthonormal, sd (k,) each component's standard deviation:
    normalised grey levels (zero mean, unit spread over a face); model_id: the face model's."""

    mean: np.ndarray
    components: np.ndarray
    sd: np.ndarray
    model_id: str = ""

    def basis(self) -> np.ndarray:
        """(V, 1 + k): the mean, then each component times its standard deviation."""
        return np.column_stack([self.mean, self.components * self.sd])

    def save(self, path: str | Path) -> None:
        np.savez_compressed(path, mean=self.mean.astype(np.float32), components=self.components.astype(np.float32),
                            sd=self.sd.astype(np.float32), model_id=np.array(self.model_id))

    @classmethod
    def load(cls, path: str | Path) -> AppearanceModel:
        """Read a model :meth:`save` wrote; ValueError with the reason when it is not one."""
        try:
            with np.load(path) as z:
                m = cls(z["mean"].astype(np.float64), z["components"].astype(np.float64), z["sd"].astype(np.float64),
                        str(z["model_id"]))
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{path} is not an appearance model (facesculpt model train-appearance): {exc}") from None
        if m.components.shape != (len(m.mean), len(m.sd)):
            raise ValueError(f"{path}: the components {m.components.shape} do not match the mean ({len(m.mean)},) "
                             f"and sd ({len(m.sd)},)")
        return m


def vertex_appearance(grey: np.ndarray, vertices: np.ndarray, projected: np.ndarray, triangles: np.ndarray,
                      perspective: bool) -> np.ndarray:
    """(V,) the face's normalised grey level at each vertex, NaN where the frame does not see it
    frontally (cosine under MIN_FRONTALITY) or it falls outside. grey (H, W) float32; vertices
    (V, 3) camera space; projected (V, 2) px; triangles (T, 3)."""
    front = frontality(vertices, vertex_normals(vertices, triangles), perspective)
    values, inside = sample(grey, projected)
    seen = inside & (front >= MIN_FRONTALITY)
    out = np.full(len(values), np.nan)
    if seen.sum() >= 10:
        v = values[seen]
        out[seen] = (v - v.mean()) / max(float(v.std()), 1e-6)
    return out


def train_appearance(samples: np.ndarray, components: int, model_id: str = "") -> AppearanceModel:
    """The mean and ``components`` leading components of ``samples`` (N, V) (NaN: unseen; a
    vertex no sample saw gets 0, the faces' mean level). ValueError for fewer than 2 samples."""
    X = np.asarray(samples, np.float64)
    if X.ndim != 2 or len(X) < 2:
        raise ValueError(f"an appearance model needs at least 2 samples (N, V), got {X.shape}")
    seen = np.isfinite(X)
    counts = seen.sum(axis=0)
    mean = np.where(counts > 0, np.nansum(np.where(seen, X, 0.0), axis=0) / np.maximum(counts, 1), 0.0)
    filled = np.where(seen, X, mean)
    k = max(0, min(int(components), len(X) - 1))
    for _ in range(FILL_ROUNDS):
        mean = filled.mean(axis=0)
        U, S, Vt = np.linalg.svd(filled - mean, full_matrices=False)
        recon = mean + (U[:, :k] * S[:k]) @ Vt[:k]
        filled = np.where(seen, X, recon)
    sd = S[:k] / np.sqrt(len(X) - 1)
    return AppearanceModel(mean, Vt[:k].T.copy(), sd, model_id)
