"""How sharp a spike a single handle vertex pulls (issue 46, item 4), per model and mesh density:
each of bench_realism's edits (its presets) solved by the project's deformer on each model's mean
face with the handles' grip at 0 (the paper's single-vertex handle) and at the old default 0.2,
next to the benchmark's truths on the Surrey model (the paper's ARAP, solved by libigl:
``realism/paper_arap.py``; the gripped ARAP: ``realism/arap_truth.py``).

Per handle, on the surface the compositor draws (the model's mesh with its holes closed, Loop
subdivided as the compositor does by default: 0 levels for the Surrey model's 6736 triangles, 2
for the face mesh's): the handle's displacement minus the mean of its 1-ring's, as a share of the
handle's (``spike``: 0 where the ring moves with it, 1 where the ring stays still), and the largest
change of a face normal (degrees) among the triangles around the handle, against the same surface
at rest. The lips' displacement in the chin edit (the largest, mm, over the mouth's border). The
mesh density: the median edge (mm) at the handle on the mesh the deformer solves.

Writes ``results.md``/``results.json``, shaded close-ups ``spike_EDIT_MODEL.png`` (rest | grip 0
| grip 0.2 | the truths on the Surrey model; frontal and turned 60 degrees) and, with
``--textured`` (default on), ``textured_EDIT.png``: bench_realism's synthetic head (textured, yaw
-25 / 0 / +25), the Surrey model's grips and the paper's truth drawn by the benchmark's reference
rasteriser with the camera zoomed ``ZOOM`` times (a face about 3x as large as the benchmark's,
as a close webcam shows it) to ``--out``.

Run: ``python -m benchmarks.bench_handle_spike [--out DIR] [--edits nose,chin,cheeks,jaw]
[--no-textured]``. Needs the shared data (../shared/data or FACESCULPT_DATA; s18.mp4 for
``--textured``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.edits import EDITS, displacement, preset
from benchmarks.realism.raster import rasterise
from facesculpt.geometry.boundary_loops import boundary_loops
from facesculpt.geometry.close_holes import close_holes
from facesculpt.geometry.subdivision import loop_subdivision
from facesculpt.geometry.vertex_normals import face_normals, vertex_normals
from facesculpt.paths import shared_data_dir

GRIPS = (0.0, 0.2)
VIEWS = ((0.0, "front"), (60.0, "turned 60"))
PANEL = 260  # close-up side, px
ZOOM = 3.0    # the textured close-ups' focal length over the benchmark's
TEXTURED_FRAMES = (45, 0, 15)  # yaw -25, 0, +25 in bench_realism's turning head


def render_mesh(triangles: np.ndarray, n_vertices: int):
    """(S (Vd, V) sparse, fine triangles): the compositor's default render mesh of a model mesh,
    its holes closed with fans and Loop subdivided as many levels as keep it within its budget
    (the model's vertex v is fine vertex v)."""
    from facesculpt.nodes.renderer.subdivision import levels_for

    closed = close_holes(np.asarray(triangles, np.int64))
    return loop_subdivision(closed, n_vertices, levels_for(len(closed)))


def spike_of(S, fine: np.ndarray, rest: np.ndarray, moved: np.ndarray, handle: int) -> tuple[float, float]:
    """(spike share, largest normal change in degrees) at ``handle`` of the fine surface
    ``S @ rest`` -> ``S @ moved`` (the model's vertex ``handle`` is fine vertex ``handle``)."""
    A, B = S @ rest, S @ moved
    d = B - A
    ring = np.unique(fine[np.any(fine == handle, axis=1)])
    ring = ring[ring != handle]
    dh = float(np.linalg.norm(d[handle]))
    spike = float(np.linalg.norm(d[handle] - d[ring].mean(axis=0))) / dh if dh > 0 else 0.0
    faces = np.flatnonzero(np.any(fine == handle, axis=1))
    unit = lambda n: n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)  # noqa: E731
    n0, n1 = unit(face_normals(A, fine[faces])), unit(face_normals(B, fine[faces]))
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n0, n1), -1.0, 1.0)))
    return spike, float(angle.max())


def mouth_border(triangles: np.ndarray, rest: np.ndarray, landmarks: dict) -> np.ndarray:
    """The vertices of the hole between the mouth corners (the lips' inner border)."""
    mid = 0.5 * (rest[landmarks["mouth_left"]] + rest[landmarks["mouth_right"]])
    loops = boundary_loops(np.asarray(triangles, np.int64))[1:]
    return min(loops, key=lambda lp: float(np.linalg.norm(rest[lp].mean(axis=0) - mid)))


def median_edge_at(rest: np.ndarray, triangles: np.ndarray, v: int) -> float:
    """The median length (mm) of the edges at vertex ``v``."""
    ring = np.unique(triangles[np.any(triangles == v, axis=1)])
    return float(np.median(np.linalg.norm(rest[ring[ring != v]] - rest[v], axis=1)))


def solve(model, doc: dict, grip: float):
    """The preset ``doc`` settled by the project's deformer on ``model``'s mean face: (the
    displacement (V, 3) mm, the handle vertices, the deformer's solve mesh)."""
    from facesculpt.nodes.deformer import EditStack

    stack = EditStack(model.mean, model.triangles, list(model.landmark_names), model.landmark_vertices, grip=grip)
    stack.apply_preset(doc)
    d = stack.settle()
    handles = sorted({h for e in stack.edits for h in e.offsets})
    return d, handles, stack.solve_mesh


def shaded(rest: np.ndarray, triangles: np.ndarray, S, fine: np.ndarray, centre: np.ndarray, yaw: float,
           half_mm: float) -> np.ndarray:
    """A grey Lambert-shaded orthographic close-up (PANEL x PANEL px, uint8) of the fine surface
    ``S @ rest``, turned ``yaw`` degrees about the vertical axis through ``centre`` (3,) mm, the
    window ``half_mm`` mm either side of it."""
    X = S @ np.asarray(rest, np.float64) - centre
    c, s_ = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    X = X @ np.array([[c, 0.0, -s_], [0.0, 1.0, 0.0], [s_, 0.0, c]]).T
    scale = PANEL / (2.0 * half_mm)
    px = np.column_stack([X[:, 0] * scale + PANEL / 2, -X[:, 1] * scale + PANEL / 2]) * 2
    frags = rasterise(px, 1000.0 - X[:, 2], fine, (0, 0, 2 * PANEL, 2 * PANEL))
    N = frags.interpolate(fine, vertex_normals(X, fine))
    N /= np.maximum(np.linalg.norm(N, axis=2, keepdims=True), 1e-12)
    light = np.array([-0.4, 0.5, 0.77])
    img = np.where(frags.covered, 40 + 200 * np.clip(N @ (light / np.linalg.norm(light)), 0, 1), 255.0)
    return cv2.resize(img.astype(np.float32), (PANEL, PANEL), interpolation=cv2.INTER_AREA).astype(np.uint8)


def labelled(img: np.ndarray, text: str) -> np.ndarray:
    out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 160), 1, cv2.LINE_AA)
    return out


def textured(spec, scene, out: Path) -> None:
    """``textured_EDIT.png``: the synthetic head at TEXTURED_FRAMES, zoomed on the edit's handles:
    input | grip 0 | grip 0.2 | the paper's truth (rows: frames)."""
    from benchmarks.realism.edits import handle_vertex
    from benchmarks.realism.raster import project, render_textured
    from facesculpt.nodes.deformer import EditStack

    n = scene.model_vertices
    rest = scene.rest[:n]
    doc = preset(spec, rest, scene.landmarks, scene.model_triangles)
    cases = {"input": np.zeros_like(scene.rest)}
    for g in GRIPS:
        stack = EditStack(rest.astype(np.float32), scene.model_triangles, list(scene.landmarks),
                          list(scene.landmarks.values()), grip=g)
        stack.apply_preset(doc)
        d = displacement(spec, scene.rest, scene.landmarks)   # the mouth's closing vertices: the falloff
        d[:n] = stack.settle()
        cases[f"grip {g:g}"] = d
    cases["truth paper"] = displacement(spec, scene.rest, scene.landmarks, "paper", scene.model_triangles, n)
    handles = [handle_vertex(h, scene.landmarks) for h in spec.handles]
    H, W = scene.background.shape[:2]
    rows = []
    for i in TEXTURED_FRAMES:
        K = scene.K.copy()
        K[:2, :2] *= ZOOM
        centre = project(K, scene.to_camera(scene.rest, i)[handles])[0].mean(axis=0)
        K[0, 2] += W / 2 - centre[0]
        K[1, 2] += H / 2 - centre[1]
        grey = np.full_like(scene.background, 128)
        row = []
        for label, d in cases.items():
            img = render_textured(K, scene.to_camera(scene.rest + d, i), scene.triangles, scene.texcoords, scene.alpha,
                                  scene.texture, grey)
            img = np.clip(np.rint(img), 0, 255).astype(np.uint8)[H // 2 - 150: H // 2 + 150, W // 2 - 150: W // 2 + 150]
            cv2.putText(img, f"{label}, yaw {scene.pose(i)[0]:+.0f}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                        (0, 0, 160), 1, cv2.LINE_AA)
            row.append(img)
        rows.append(np.hstack(row))
    cv2.imwrite(str(out / f"textured_{spec.name}.png"), np.vstack(rows))


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--edits", default="nose,chin,cheeks,jaw", help="bench_realism edits (default nose,chin,cheeks,jaw)")
    p.add_argument("--textured", action=argparse.BooleanOptionalAction, default=True,
                   help="also draw the textured synthetic head zoomed on each edit (default on)")
    a = p.parse_args(argv)
    a.edits = [e for e in a.edits.split(",") if e]
    bad = [e for e in a.edits if e not in EDITS]
    if bad:
        p.error(f"unknown edit {bad[0]!r} (choose from {', '.join(EDITS)})")
    return a


def measure_edit(spec, models: dict, sfm_landmarks: dict, out: Path) -> list[dict]:
    """The rows of one edit (per model and grip, and the truths on the Surrey model), and its
    close-ups written to ``out``."""
    sfm = models["sfm"]
    doc = preset(spec, sfm.mean, sfm_landmarks, sfm.triangles)
    rows, panels = [], {}
    for name, model in models.items():
        S, fine = render_mesh(model.triangles, len(model.mean))
        landmarks = {str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)}
        lips = mouth_border(model.triangles, model.mean, landmarks)
        cases = [(f"grip {g:g}", *solve(model, doc, g)) for g in GRIPS]
        if name == "sfm":
            handles = cases[0][2]
            for truth in ("paper", "arap"):
                d = displacement(spec, model.mean, sfm_landmarks, truth, model.triangles, len(model.mean))
                cases.append((f"truth {truth}", d, handles, None))
        for label, d, handles, mesh in cases:
            moved = model.mean + d
            for h in handles:
                spike, normal = spike_of(S, fine, model.mean, moved, h)
                rows.append({"edit": spec.name, "model": name, "case": label, "handle": int(h),
                             "pull_mm": float(np.linalg.norm(d[h])), "spike": spike, "normal_deg": normal,
                             "lips_mm": float(np.linalg.norm(d[lips], axis=1).max()),
                             "edge_mm": median_edge_at(model.mean if mesh is None else mesh.rest,
                                                       model.triangles if mesh is None else mesh.triangles, h)})
            centre = model.mean[handles].mean(axis=0)
            half = max(22.0, 0.75 * spec.radius) if len(handles) == 1 else 0.9 * spec.radius + 20
            panels[name, label] = [shaded(moved, model.triangles, S, fine, centre, yaw, half) for yaw, _ in VIEWS]
        rest_views = [shaded(model.mean, model.triangles, S, fine, model.mean[cases[0][2]].mean(axis=0), yaw,
                             max(22.0, 0.75 * spec.radius) if len(cases[0][2]) == 1 else 0.9 * spec.radius + 20)
                      for yaw, _ in VIEWS]
        grid = []
        for k, (_, view) in enumerate(VIEWS):
            row = [labelled(rest_views[k], f"{name} rest, {view}")]
            row += [labelled(panels[name, label][k], label) for label, *_ in cases]
            grid.append(np.hstack(row))
        cv2.imwrite(str(out / f"spike_{spec.name}_{name}.png"), np.vstack(grid))
    return rows


def markdown(rows: list[dict]) -> str:
    head = ("| edit | model | case | handle | pull mm | edge at handle mm | spike (share) | normal change deg | "
            "lips mm |\n| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    lines = [f"| {r['edit']} | {r['model']} | {r['case']} | {r['handle']} | {r['pull_mm']:.2f} | {r['edge_mm']:.2f} | "
             f"{r['spike']:.2f} | {r['normal_deg']:.1f} | {r['lips_mm']:.2f} |" for r in rows]
    return "# bench_handle_spike\n\n" + "\n".join([head, *lines]) + "\n"


def main(argv=None) -> int:
    args = parse_args(argv)
    data = shared_data_dir()
    if data is None or not (data / "sfm").is_dir():
        print("bench_handle_spike needs the shared data (../shared/data or FACESCULPT_DATA: sfm/)", file=sys.stderr)
        return 2
    from facesculpt.nodes.fitter import load_model

    out = args.out or Path(tempfile.mkdtemp(prefix="bench_handle_spike_"))
    out.mkdir(parents=True, exist_ok=True)
    models = {"sfm": load_model("sfm"), "facemesh": load_model("facemesh")}
    sfm = models["sfm"]
    sfm_landmarks = {str(k): int(v) for k, v in zip(sfm.landmark_names, sfm.landmark_vertices)}
    rows = [r for e in args.edits for r in measure_edit(EDITS[e], models, sfm_landmarks, out)]
    if args.textured:
        from benchmarks.realism.scene import make_scene

        scene = make_scene(data, max(TEXTURED_FRAMES) + 1)
        for e in args.edits:
            textured(EDITS[e], scene, out)
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    text = markdown(rows)
    (out / "results.md").write_text(text)
    print(text)
    print(f"results and close-ups in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
