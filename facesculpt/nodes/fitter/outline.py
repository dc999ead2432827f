"""Outline (face contour) correspondences — the paper's §2.1, Fig. 3c.

Outline landmarks (iBUG 1-8 and 10-17) mark the face's silhouette, which slides over the model as the
head turns, so they cannot belong to fixed vertices. For each of them:

1. candidates: the model's outline vertices of that side (:func:`outline_band`: the eos contour and
   everything inside it but the nose, where the silhouette lies when the head turns) that face
   the camera and are not occluded (:func:`visible_candidates`);
2. the three candidates whose projections are nearest to the landmark;
3. the point where the landmark's back-projected ray meets their triangle — the barycentric point
   of the triangle (perspective-correct) whose projection is the landmark, or the triangle's point
   nearest to it when the ray misses — one correspondence per landmark
   (:func:`outline_correspondences`, ``mode="ray"``). ``mode="nearest"`` keeps the simple
   nearest-vertex search for comparison.

A correspondence is returned as three vertex indices and three barycentric weights, so it stays
linear in the model coefficients: point = Σ w_k · vertex_k(alpha, beta).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from facesculpt.geometry import point_bounds


def nose_region(mean: np.ndarray, landmarks: dict[str, int]) -> np.ndarray:
    """(V,) bool: the protruding nose — vertices between the nose bridge (iBUG 28) and 3 mm below the
    nose-lip junction (34) in height, within 4 mm beyond the nostrils' half width (32-36) of the
    nose's midline, and in front of the nostrils' depth (minus 3 mm). Outline landmarks never lie on
    the nose (annotators follow the cheek and jaw even where the nose juts out past them), so it is
    no outline candidate. All False when the model lacks those landmarks."""
    if not all(k in landmarks for k in ("28", "32", "34", "36")):
        return np.zeros(len(mean), bool)
    p = {k: mean[landmarks[k]] for k in ("28", "32", "34", "36")}
    half = 0.5 * abs(p["36"][0] - p["32"][0]) + 4.0
    mid = 0.5 * (p["36"][0] + p["32"][0])
    return ((np.abs(mean[:, 0] - mid) < half) & (mean[:, 1] < p["28"][1]) & (mean[:, 1] > p["34"][1] - 3.0)
            & (mean[:, 2] > min(p["32"][2], p["36"][2]) - 3.0))


def outline_band(mean: np.ndarray, contour: np.ndarray, exclude: np.ndarray | None = None) -> np.ndarray:
    """Vertices that may carry one side's outline, (N,) int32: all vertices on that side of the face
    (seen from the front; within 5 % of the outline's width past the midline, so both sides share
    the chin) up to the height of the top of the contour, except ``exclude`` (V,) bool (the nose).
    As the head turns the silhouette moves from the contour across the cheek, jaw, and at large yaw
    the brow and eye region, so all of these are candidates.

    mean (V, 3) model space; contour (C,) vertex indices along that side's face outline."""
    crel = mean[contour]
    side = np.sign(np.median(crel[:, 0] - mean[:, 0].mean()))
    centre_x = 0.5 * (mean[:, 0].max() + mean[:, 0].min())
    margin = 0.05 * np.abs(crel[:, 0] - centre_x).max()
    band = (side * (mean[:, 0] - centre_x) >= -margin) & (mean[:, 1] <= crel[:, 1].max())
    if exclude is not None:
        band &= ~exclude
    band[np.asarray(contour)] = True
    return np.flatnonzero(band).astype(np.int32)


class OutlineGeometry:
    """Precomputed mesh adjacency for the visibility tests of the outline candidates.

    triangles (T, 3) of the model; candidates (N,) the union of both sides' outline vertices;
    transparent (V,) bool vertices that do not count as occluders."""

    def __init__(self, triangles: np.ndarray, candidates: np.ndarray, num_vertices: int, transparent: np.ndarray | None = None):
        self.triangles = np.asarray(triangles, np.int64)
        self.candidates = np.asarray(candidates, np.int64)
        # Vertices that may hide a candidate: all but the ``transparent`` ones (the nose — outline
        # landmarks are annotated on the cheek line even where the nose hides it).
        self.occluders = np.flatnonzero(~transparent) if transparent is not None else np.arange(num_vertices)
        touching = np.isin(self.triangles, self.candidates).any(axis=1)
        self.cand_tris = self.triangles[touching]
        # Sparse incidence: candidate row <- triangle column, to sum face normals per vertex.
        lookup = -np.ones(num_vertices, np.int64)
        lookup[self.candidates] = np.arange(len(self.candidates))
        rows = lookup[self.cand_tris].reshape(-1)
        cols = np.repeat(np.arange(len(self.cand_tris)), 3)
        keep = rows >= 0
        self.incidence = csr_matrix(
            (np.ones(keep.sum()), (rows[keep], cols[keep])), shape=(len(self.candidates), len(self.cand_tris))
        )

        # Undirected edges of those triangles with their one or two faces (-1: mesh boundary).
        e = np.concatenate([self.cand_tris[:, [0, 1]], self.cand_tris[:, [1, 2]], self.cand_tris[:, [2, 0]]])
        f = np.tile(np.arange(len(self.cand_tris)), 3)
        key = np.sort(e, axis=1)
        order = np.lexsort((key[:, 1], key[:, 0]))
        key, f = key[order], f[order]
        first = np.r_[True, (key[1:] != key[:-1]).any(axis=1)]
        starts = np.flatnonzero(first)
        counts = np.diff(np.r_[starts, len(key)])
        self.edges = key[starts]
        self.edge_faces = np.full((len(starts), 2), -1, np.int64)
        self.edge_faces[:, 0] = f[starts]
        two = counts >= 2
        self.edge_faces[two, 1] = f[starts[two] + 1]
        self._lookup = lookup

    def face_normals(self, vertices_cam: np.ndarray) -> np.ndarray:
        """(F, 3) unnormalised normals of the triangles touching the candidates, camera space."""
        t = self.cand_tris
        a = vertices_cam[t[:, 0]]
        u = vertices_cam[t[:, 1]] - a
        v = vertices_cam[t[:, 2]] - a
        # np.cross is slow for many short vectors; spell it out.
        return np.column_stack([u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
                                u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                                u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]])

    def normals(self, vertices_cam: np.ndarray, face_normals: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) area-weighted normals of the candidates in camera space (unnormalised)."""
        fn = self.face_normals(vertices_cam) if face_normals is None else face_normals
        return self.incidence @ fn

    def rim(self, face_facing: np.ndarray) -> np.ndarray:
        """(N,) bool over the candidates: endpoints of rim edges — edges between a triangle facing the
        camera and one facing away (the occluding contour), or open mesh edges of a facing triangle."""
        f0, f1 = self.edge_faces[:, 0], self.edge_faces[:, 1]
        a = face_facing[f0]
        b = np.where(f1 >= 0, face_facing[np.maximum(f1, 0)], False)
        rim_edges = self.edges[a != b]
        out = np.zeros(len(self.candidates), bool)
        idx = self._lookup[rim_edges.reshape(-1)]
        out[idx[idx >= 0]] = True
        return out


def occluded(
    query_xy: np.ndarray, query_depth: np.ndarray, all_xy: np.ndarray, all_depth: np.ndarray,
    cell: float, tolerance: float,
) -> np.ndarray:
    """(N,) bool: a query point is occluded when some mesh vertex in its image cell (of size
    ``cell`` px, about one mesh edge) lies more than ``tolerance`` closer to the camera. A coarse
    vertex-splat z-buffer: enough to drop outline candidates hidden behind the nose; the tolerance
    must exceed the depth range a grazing surface spans within one cell (the silhouette itself)."""
    lo = point_bounds(all_xy)[0]
    gi = np.floor((all_xy - lo) / cell).astype(np.int64)
    shape = point_bounds(gi)[1] + 3
    zbuf = np.full(shape[0] * shape[1], np.inf)
    flat = (gi[:, 0] + 1) * shape[1] + (gi[:, 1] + 1)
    np.minimum.at(zbuf, flat, all_depth)
    zbuf = zbuf.reshape(shape)
    qi = np.floor((query_xy - lo) / cell).astype(np.int64) + 1
    qi = np.clip(qi, 0, shape - 1)
    return zbuf[qi[:, 0], qi[:, 1]] < query_depth - tolerance


def visible_candidates(
    geometry: OutlineGeometry,
    vertices_cam: np.ndarray,
    projected: np.ndarray,
    perspective: bool,
    occlusion_tolerance: float,
    cell: float,
    facing_margin: float = 0.17,
    rim_only: bool = True,
) -> np.ndarray:
    """(N,) bool over ``geometry.candidates``: facing the camera and not occluded.

    vertices_cam (V, 3) camera space (x right, y down, z away from the camera); projected (V, 2) px;
    occlusion_tolerance in camera-space depth units; cell in px; facing_margin: largest cosine
    between a vertex normal and the viewing ray still counted as facing (0.17: 10° past the rim);
    rim_only: keep only vertices on the current outline (:meth:`OutlineGeometry.rim`) — without it an
    outline landmark that falls inside the model's projection would match an interior point and
    never pull the outline inward."""
    cand = geometry.candidates
    fn = geometry.face_normals(vertices_cam)
    n = geometry.normals(vertices_cam, fn)
    view = vertices_cam[cand] if perspective else np.array([0.0, 0.0, 1.0])
    # Rim vertices, whose normals are nearly perpendicular to the view, bound the silhouette edges
    # the outline lies on: accept normals up to ~10° past perpendicular.
    cos = (n * view).sum(axis=-1) / (np.linalg.norm(n, axis=-1) * np.linalg.norm(view, axis=-1) + 1e-30)
    facing = cos < facing_margin
    occ = geometry.occluders
    hidden = occluded(projected[cand], vertices_cam[cand, 2], projected[occ], vertices_cam[occ, 2], cell, occlusion_tolerance)
    visible = facing & ~hidden
    if rim_only:
        if perspective:
            # The normal is perpendicular to its triangle: any of its corners gives the centroid's dot product.
            corner = vertices_cam[geometry.cand_tris[:, 0]]
            face_facing = (fn * corner).sum(axis=1) < 0
        else:
            face_facing = fn[:, 2] < 0
        visible &= geometry.rim(face_facing)
    return visible


def closest_point_barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric weights (K, 3) of the point of each 2D triangle (a, b, c) nearest to p (all (K, 2)):
    p's own barycentric coordinates when it lies inside, else the nearest point of the three edges.
    Degenerate (collinear) triangles reduce to their edges."""
    K = len(p)
    v0, v1, v2 = b - a, c - a, p - a
    d00 = (v0 * v0).sum(1)
    d01 = (v0 * v1).sum(1)
    d11 = (v1 * v1).sum(1)
    d20 = (v2 * v0).sum(1)
    d21 = (v2 * v1).sum(1)
    denom = d00 * d11 - d01 * d01
    scale = np.maximum(d00 * d11, 1e-30)
    good = denom > 1e-9 * scale
    safe = np.where(good, denom, 1.0)
    wb = (d11 * d20 - d01 * d21) / safe
    wc = (d00 * d21 - d01 * d20) / safe
    wa = 1 - wb - wc
    inside = good & (wa >= 0) & (wb >= 0) & (wc >= 0)
    best_w = np.zeros((K, 3))
    best_d = np.full(K, np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        P = (a, b, c)
        e = P[j] - P[i]
        ee = np.maximum((e * e).sum(1), 1e-30)
        t = np.clip(((p - P[i]) * e).sum(1) / ee, 0.0, 1.0)
        q = P[i] + t[:, None] * e
        d = ((p - q) ** 2).sum(1)
        better = d < best_d
        w = np.zeros((K, 3))
        w[:, i] = 1 - t
        w[:, j] = t
        best_w[better] = w[better]
        best_d[better] = d[better]
    best_w[inside] = np.column_stack([wa, wb, wc])[inside]
    return best_w


def outline_correspondences(
    landmarks2d: np.ndarray,
    candidates: np.ndarray,
    projected: np.ndarray,
    depth: np.ndarray | None = None,
    mode: str = "ray",
) -> tuple[np.ndarray, np.ndarray]:
    """One model point per outline landmark.

    landmarks2d (K, 2) px of one side; candidates (N,) visible outline vertex indices of that side;
    projected (V, 2) px of all vertices; depth (V,) camera-space z for perspective-correct weights
    (None under orthographic projection); mode "ray" (three nearest candidates, the ray-triangle
    point) or "nearest" (the nearest candidate vertex). Returns vertex indices (K, 3) int and
    barycentric weights (K, 3) float64 (rows sum to 1)."""
    K = len(landmarks2d)
    if len(candidates) == 0:
        raise ValueError("no visible outline candidates")
    cp = projected[candidates]
    d2 = ((landmarks2d[:, None, :] - cp[None, :, :]) ** 2).sum(-1)  # (K, N)
    if mode == "nearest" or len(candidates) < 3:
        nearest = candidates[np.argmin(d2, axis=1)]
        return np.repeat(nearest[:, None], 3, axis=1), np.tile([1.0, 0.0, 0.0], (K, 1))
    if mode != "ray":
        raise ValueError(f"outline mode must be 'ray' or 'nearest', got {mode!r}")
    three = np.argpartition(d2, 2, axis=1)[:, :3]
    verts = candidates[three]  # (K, 3)
    a, b, c = projected[verts[:, 0]], projected[verts[:, 1]], projected[verts[:, 2]]
    w = closest_point_barycentric(landmarks2d, a, b, c)
    if depth is not None:
        # Screen-space weights -> the 3D point on the triangle that projects there.
        w = w / depth[verts]
        w /= w.sum(axis=1, keepdims=True)
    return verts, w
