"""The face-mesh triangle list, rebuilt from mediapipe's tessellation edges.

mediapipe ships the 468-point mesh topology only as edge sets in
``mediapipe/python/solutions/face_mesh_connections.py``. That file is read here as data
(``ast``, never imported). The triangles are the 3-cliques of the tessellation graph that are
faces: a clique whose three edges each belong to more than two cliques is a "separating"
triangle around a vertex fan, not a face, and is dropped. The faces are then oriented
consistently by walking across shared edges, and the global sign is fixed by anatomy.

Orientation convention: counter-clockwise as seen from the camera (OpenGL's default front
face), i.e. for a face towards the camera the 2-D cross product of the triangle's edges in
image pixel coordinates (x right, y down) is negative. The outer boundary of the mesh then runs
forehead (10) -> right cheek, image left (234) -> chin (152) -> left cheek, image right (454).
"""

from __future__ import annotations

import ast
import itertools
from collections import Counter, defaultdict, deque

import numpy as np

NUM_POINTS = 468
# Outer-boundary anchors of the face oval, in the order a counter-clockwise boundary visits them.
FOREHEAD, RIGHT_CHEEK, CHIN, LEFT_CHEEK = 10, 234, 152, 454


class TessellationError(ValueError):
    """The edge set does not describe an orientable triangle mesh as expected."""


def parse_connections(source: str) -> dict[str, list[tuple[int, int]]]:
    """Edge sets of face_mesh_connections.py, read with ``ast`` (the file is never executed).

    Returns ``{name: [(a, b), ...]}`` for every top-level ``NAME = frozenset([...])`` whose
    argument is a literal list of integer pairs.
    """
    out: dict[str, list[tuple[int, int]]] = {}
    for node in ast.parse(source).body:
        if not (isinstance(node, ast.Assign) and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name) and isinstance(node.value, ast.Call)):
            continue
        call = node.value
        if not (isinstance(call.func, ast.Name) and call.func.id == "frozenset" and len(call.args) == 1):
            continue
        try:
            edges = ast.literal_eval(call.args[0])
        except ValueError:
            continue  # a union of other sets, not a literal
        if isinstance(edges, (list, tuple)) and all(
                isinstance(e, tuple) and len(e) == 2 and all(isinstance(v, int) for v in e) for e in edges):
            out[node.targets[0].id] = [tuple(e) for e in edges]
    return out


def _orient(faces: list[tuple[int, int, int]]) -> list[tuple[int, int, int]]:
    """Flip faces so that every interior edge is traversed in opposite directions by its two faces."""
    by_edge: dict[tuple[int, int], list[int]] = defaultdict(list)
    for fi, f in enumerate(faces):
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            by_edge[(min(a, b), max(a, b))].append(fi)
    oriented: list[tuple[int, int, int] | None] = [None] * len(faces)
    for seed in range(len(faces)):
        if oriented[seed] is not None:
            continue
        oriented[seed] = faces[seed]
        queue = deque([seed])
        while queue:
            fi = queue.popleft()
            f = oriented[fi]
            for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
                for nj in by_edge[(min(a, b), max(a, b))]:
                    if nj == fi:
                        continue
                    g = faces[nj]
                    # The neighbour must traverse the shared edge as b -> a.
                    has_ab = any((g[k], g[(k + 1) % 3]) == (a, b) for k in range(3))
                    want = (g[0], g[2], g[1]) if has_ab else g
                    if oriented[nj] is None:
                        oriented[nj] = want
                        queue.append(nj)
                    elif oriented[nj] != want:
                        raise TessellationError("the face mesh is not orientable")
    return [f for f in oriented if f is not None]


def _outer_loop(faces: list[tuple[int, int, int]]) -> list[int]:
    """The boundary loop through the forehead point, in the direction the faces induce."""
    directed = Counter()
    for f in faces:
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            directed[(a, b)] += 1
    nxt = {a: b for (a, b) in directed if (b, a) not in directed}
    if FOREHEAD not in nxt:
        raise TessellationError(f"point {FOREHEAD} (forehead) is not on the mesh boundary")
    loop, v = [FOREHEAD], nxt[FOREHEAD]
    while v != FOREHEAD:
        loop.append(v)
        if v not in nxt or len(loop) > len(nxt):
            raise TessellationError("the outer boundary of the mesh is not a simple loop")
        v = nxt[v]
    return loop


def triangles_from_edges(edges) -> np.ndarray:
    """Faces of the face-mesh tessellation graph, consistently oriented (see module docstring).

    ``edges``: iterable of (a, b) point pairs, either direction. Returns ``(T, 3) int32``
    point indices (852 faces for mediapipe 0.10.14's 468-point mesh).
    """
    undirected = {(min(a, b), max(a, b)) for a, b in edges if a != b}
    adj: dict[int, set[int]] = defaultdict(set)
    for a, b in undirected:
        adj[a].add(b)
        adj[b].add(a)
    cliques = set()
    for a, b in undirected:
        for c in adj[a] & adj[b]:
            cliques.add(tuple(sorted((a, b, c))))
    per_edge = Counter(e for t in cliques for e in itertools.combinations(t, 2))
    faces = sorted(t for t in cliques if not all(per_edge[e] > 2 for e in itertools.combinations(t, 2)))
    per_edge = Counter(e for t in faces for e in itertools.combinations(t, 2))
    if not faces or max(per_edge.values()) > 2:
        raise TessellationError("the tessellation edges do not form a manifold triangle mesh")
    faces = _orient(faces)
    loop = _outer_loop(faces)
    try:
        order = [loop.index(v) for v in (RIGHT_CHEEK, CHIN, LEFT_CHEEK)]
    except ValueError as exc:
        raise TessellationError("the face-oval anchor points are not on the outer boundary") from exc
    if order == sorted(order):
        pass  # already forehead -> right cheek -> chin -> left cheek (counter-clockwise on screen)
    elif order == sorted(order, reverse=True):
        faces = [(a, c, b) for a, b, c in faces]
    else:
        raise TessellationError("the face-oval anchor points are not in a consistent order")
    return np.asarray(faces, dtype=np.int32)
