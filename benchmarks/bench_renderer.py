"""Renderer time per frame at 856x480, next to OpenCV's Telea inpainting of the same mask on the
full frame and next to the compositor of an earlier commit, in the same run.

    python -m benchmarks.bench_renderer [--video s18] [--frames 60] [--model sfm|facemesh]
                                        [--baseline REV] [--json out.json]

Frames: the shared video (default s18.mp4, 1280x720) resized to 856x480, the paper's size. Face
geometry per frame from the real pipeline (landmark detector + fitter, orthographic) when
`facesculpt setup` has run, else the Surrey Face Model posed on frame 0 by hand-marked landmarks
(tests/renderer_scene.py). The edit is the issue's (nose tip out 15 mm, cheeks in 8 mm; ARAP),
merged per frame with the deformer's Eq. 5. Geometry is computed before timing.

Measured per frame (medians, ms): the compositor's stages (camera recovery with the subdivided
vertices, draw (the source map), readback, masks (regions, uncovered mask, sources), inpaint (the
fill), texture (the frame sampled through the source map), composite) and its total, with the
push-pull fill, with Telea on the bounding box, with the drag fill (the default), with Navier-Stokes,
with the patch fill, with the background plate on (issue 16: push-pull, patch or drag under it; people kept off it as
in process, and with drag once learning everywhere outside the face as before), with Lanczos-4 sampling instead of bicubic, and
the whole render of the baseline compositor (``--baseline``, default the commit before the
source-map warp: texture round trip, no subdivision), loaded from git; the peer cv2.inpaint(TELEA, radius 3) of the same uncovered mask on the full
frame; and a GPU variant of the composite step (upload background + alpha, blend in a shader,
read back) next to the CPU one. Targets: inpaint <= 0.1x the full-frame Telea; whole renderer
stage <= 10 ms on this machine. The paper (i7-3770 + GTX TITAN): inpainting 31.16 ms, texture +
texcoord update + rendering 10.55 ms.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import cv2
import moderngl
import numpy as np

REPO = Path(__file__).resolve().parent.parent

from benchmarks.renderer_scene import issue_edit, place_fitted, place_marked, read_frames  # noqa: E402
from facesculpt.geometry import merge_deformation  # noqa: E402
from facesculpt.nodes.renderer import Compositor  # noqa: E402
from facesculpt.nodes.renderer.person_segmentation import NETWORK_FILE, PersonSegmenter  # noqa: E402
from facesculpt.nodes.renderer.texture_atlas import uv_layout  # noqa: E402
from facesculpt.paths import model_home, shared_data_dir  # noqa: E402
from facesculpt.runtime.process_limits import limit_threads  # noqa: E402

BASELINE_REV = "7c619da"  # the compositor before the source-map warp (issue 15)
FILL_VARIANTS = (("drag", "drag", False), ("ns", "ns", False), ("patch", "patch", False),
                 ("pushpull+plate", "pushpull", True), ("patch+plate", "patch", True), ("drag+plate", "drag", True),
                 ("drag+plate-face-only", "drag", "face only"))  # plate True: people kept off it, as in process
#: Issue 16's renderer with the plate and the texture atlas on, as the live renderer runs it (the
#: atlas updated every ATLAS_EVERY frames on a thread of its own, people kept off the plate; the
#: update, which starts once the frame is drawn, is waited for untimed: the live renderer has that
#: time while it waits for the next frame).
ATLAS_VARIANT, ATLAS_EVERY = "drag+plate+atlas", 2
#: Between a frame's arrival and its render, the live graph fits the face (s): the plate's people
#: are looked for meanwhile (Compositor.prefetch).
FIT_PAUSE_S = 0.010
PAPER_INPAINT_MS = 31.16
PAPER_TEXTURE_DRAW_MS = 10.55
SIZE = (856, 480)


def geometry(frames, model_name: str):
    """Per frame: (fitted, projected, triangles, deformed); the source's words, the model's id and
    its (V, 2) UV layout for the atlas."""
    from facesculpt.nodes.fitter import FitterConfig, facemesh_model, load_model, make_fitter

    model = load_model("sfm") if model_name == "sfm" else facemesh_model()
    out = []
    if (model_home() / "manifest.json").is_file():
        from facesculpt.geometry import to_ibug68
        from facesculpt.nodes.landmarks import LandmarkDetector

        detector = LandmarkDetector()
        first = place_fitted(model, frames[0], detector)
        edit = issue_edit(first)
        fitter = make_fitter(model, FitterConfig(), SIZE)
        source = "detector + fitter per frame"
        for i, frame in enumerate(frames):
            faces = detector.track(frame)
            if not faces:
                out.append(None)
                continue
            pts = faces[0].points
            r = fitter.fit(pts if model.dense else to_ibug68(pts), stamp=i / 30.0)
            deformed = merge_deformation(r.vertices, r.R, r.scale, edit)
            out.append((r.vertices, r.projected, model.triangles, deformed))
    else:
        if model_name != "sfm":
            raise SystemExit("the face-mesh model needs `facesculpt setup`")
        pose = place_marked(model, "s18")
        edit = issue_edit(pose)
        deformed = merge_deformation(pose.fitted, pose.R, pose.scale, edit)
        source = "SFM posed by hand-marked landmarks on frame 0 (no networks: run `facesculpt setup`)"
        out = [(pose.fitted, pose.projected, pose.triangles, deformed)] * len(frames)
    return out, source, model.model_id, uv_layout(model.mean.reshape(-1, 3), model.texcoords)


def baseline_compositor(rev: str):
    """The Compositor class of ``facesculpt/nodes/renderer/compositor.py`` (``nodes/...`` before the
    layout move) at git revision ``rev`` (its
    relative imports resolved in today's package), or None when git cannot show it."""
    import importlib.util
    import subprocess
    import tempfile

    source = None
    for path in ("facesculpt/nodes/renderer/compositor.py", "nodes/renderer/compositor.py"):  # after, before the move
        try:
            source = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:{path}"],
                                    capture_output=True, text=True, check=True).stdout
            break
        except (OSError, subprocess.CalledProcessError):
            continue
    if source is None:
        return None
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(source)
    spec = importlib.util.spec_from_file_location("facesculpt.nodes.renderer._baseline_compositor", f.name)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "facesculpt.nodes.renderer"
    spec.loader.exec_module(module)
    Path(f.name).unlink()
    return module.Compositor


class GpuComposite:
    """The composite step on the GPU, for comparison: background and alpha crops uploaded, the
    face sampled from a texture, blended in a fragment shader, the crop read back."""

    def __init__(self, ctx: moderngl.Context, width: int, height: int):
        self.ctx = ctx
        self.face = ctx.texture((width, height), 4)
        self.bg = ctx.texture((width, height), 3)
        self.alpha = ctx.texture((width, height), 1, dtype="f4")
        self.target = ctx.texture((width, height), 3)
        self.fbo = ctx.framebuffer([self.target])
        self.prog = ctx.program(
            vertex_shader="""#version 330
                in vec2 p; out vec2 uv; uniform vec2 scale;
                void main() { gl_Position = vec4(p, 0, 1); uv = (p * 0.5 + 0.5) * scale; }""",
            fragment_shader="""#version 330
                uniform sampler2D face; uniform sampler2D bg; uniform sampler2D alpha;
                in vec2 uv; out vec4 c;
                void main() { float a = texture(alpha, uv).r;
                              c = vec4(mix(texture(bg, uv).rgb, texture(face, uv).rgb, a), 1); }""")
        self.prog["face"], self.prog["bg"], self.prog["alpha"] = 0, 1, 2
        self.vao = ctx.vertex_array(self.prog, [(ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], "f4")), "2f", "p")])
        self.size = (width, height)

    def run(self, face_rgba: np.ndarray, background: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        h, w = background.shape[:2]
        self.face.write(face_rgba, viewport=(0, 0, w, h))  # (already on the GPU in a GPU design)
        t0 = time.perf_counter()
        self.bg.write(np.ascontiguousarray(background), viewport=(0, 0, w, h))
        self.alpha.write(np.ascontiguousarray(alpha, np.float32), viewport=(0, 0, w, h))
        self.fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        self.prog["scale"].value = (w / self.size[0], h / self.size[1])
        self.face.use(0), self.bg.use(1), self.alpha.use(2)
        self.vao.render(moderngl.TRIANGLE_STRIP)
        out = np.frombuffer(self.fbo.read(viewport=(0, 0, w, h), components=3, alignment=1), np.uint8)
        dt = time.perf_counter() - t0
        return out.reshape(h, w, 3), dt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default="s18")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--model", default="sfm", choices=("sfm", "facemesh"))
    ap.add_argument("--rounds", type=int, default=2, help="passes over the frames (the first warms up)")
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--baseline", default=BASELINE_REV,
                    help=f"git revision whose compositor is timed alongside (default {BASELINE_REV}; '' for none)")
    ap.add_argument("--threads", type=int, default=1,
                    help="OpenBLAS and OpenCV threads, as in the renderer node (default 1; 0: the libraries' defaults)")
    args = ap.parse_args(argv)
    limit_threads(args.threads)  # the renderer node runs with one thread (facesculpt.runtime.process_limits)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    frames = read_frames(data, args.video, args.frames, size=SIZE)
    geo, source, model_id, uv = geometry(frames, args.model)
    W, H = SIZE
    comps = {m: Compositor(W, H, inpaint=m) for m in ("pushpull", "telea")}
    comps["lanczos"] = Compositor(W, H, ctx=comps["pushpull"].ctx, interpolation="lanczos")
    # issue 16: the other fills and the background plate (learned every frame, registered)
    people = PersonSegmenter() if (model_home() / NETWORK_FILE).is_file() else None
    for name, fill, plate in FILL_VARIANTS:
        comps[name] = Compositor(W, H, ctx=comps["pushpull"].ctx, inpaint=fill, plate=bool(plate),
                                 segmenter=people if plate is True else None)
    comps[ATLAS_VARIANT] = Compositor(W, H, ctx=comps["pushpull"].ctx, inpaint="drag", plate=True, segmenter=people,
                                      atlas=True, atlas_every=ATLAS_EVERY, atlas_thread=True)
    Baseline = baseline_compositor(args.baseline) if args.baseline else None
    if Baseline is not None:
        comps["baseline"] = Baseline(W, H, ctx=comps["pushpull"].ctx)
    gpu = GpuComposite(comps["pushpull"].ctx, W, H)
    stats: dict[str, list[float]] = {}

    def add(key, ms):
        stats.setdefault(key, []).append(ms)

    for rnd in range(args.rounds):
        for frame, g in zip(frames, geo):
            if g is None:
                continue
            fitted, projected, tris, deformed = g
            # as the renderer node does: the plate's people are looked for as soon as the frame
            # arrives, while its face is fitted (here: a pause as long as a fit)
            for comp in comps.values():
                if hasattr(comp, "prefetch"):
                    comp.prefetch(frame)
            time.sleep(FIT_PAUSE_S)
            for method, comp in comps.items():
                t0 = time.perf_counter()
                memory = {"uv": uv} if method == ATLAS_VARIANT else {}
                out = comp.render(frame, fitted, projected, tris, deformed, **memory)
                wall = (time.perf_counter() - t0) * 1e3
                if getattr(comp, "memory", None) is not None:   # a live renderer's update runs while it waits for the next frame
                    comp.memory.wait()
                if rnd == 0:
                    continue
                for k, v in comp.timings.items():
                    add(f"{method}.{k}", v)
                add(f"{method}.wall", wall)
            if rnd == 0:
                continue
            comp = comps["pushpull"]
            if comp.box is None:
                continue
            full = np.zeros((H, W), np.uint8)
            x0, y0, x1, y1 = comp.box
            full[y0:y1, x0:x1] = comp.inpainted_region
            add("mask_px", float(full.sum()))
            if full.any():
                t0 = time.perf_counter()
                cv2.inpaint(frame, full, 3.0, cv2.INPAINT_TELEA)
                add("cv2_telea_full_frame", (time.perf_counter() - t0) * 1e3)
                add("pushpull.inpaint_with_mask", comp.timings["inpaint"])
            # Composite step: CPU (as the compositor does) vs GPU, on this frame's crop.
            crop = out[y0:y1, x0:x1]
            dmask = comp.deformed_region
            alpha = np.minimum(cv2.distanceTransform(dmask, cv2.DIST_L2, 3) / comp.feather_px, 1.0)
            face = np.dstack([crop, np.full(crop.shape[:2], 255, np.uint8)])
            t0 = time.perf_counter()
            blended = cv2.blendLinear(crop, crop, alpha, 1.0 - alpha)
            np.copyto(crop.copy(), blended, where=(dmask > 0)[..., None])
            add("composite_cpu_blend", (time.perf_counter() - t0) * 1e3)
            _, dt = gpu.run(face, crop, alpha)
            add("composite_gpu_blend", dt * 1e3)

    med = {k: statistics.median(v) for k, v in stats.items()}
    n = len(stats.get("pushpull.total", []))
    fig = {
        "video": args.video, "size": SIZE, "model": model_id, "geometry": source, "frames_timed": n,
        "renderer": comps["pushpull"].ctx.info.get("GL_RENDERER", "?"),
        "median_ms": {k: round(v, 3) for k, v in med.items()},
    }
    pp, te = "pushpull", "telea"
    tex_draw = med[f"{pp}.texture"] + med[f"{pp}.draw"] + med[f"{pp}.readback"]
    fig["ratios"] = {
        "pushpull_inpaint / cv2_telea_full_frame": round(med["pushpull.inpaint_with_mask"] / med["cv2_telea_full_frame"], 4)
        if "cv2_telea_full_frame" in med else None,
        "telea_bbox_inpaint / cv2_telea_full_frame": round(med[f"{te}.inpaint"] / med["cv2_telea_full_frame"], 4)
        if "cv2_telea_full_frame" in med else None,
        "pushpull_inpaint / paper_inpaint": round(med["pushpull.inpaint_with_mask"] / PAPER_INPAINT_MS, 4)
        if "pushpull.inpaint_with_mask" in med else None,
        "texture_draw_readback / paper_texture_draw": round(tex_draw / PAPER_TEXTURE_DRAW_MS, 4),
        "composite_gpu / composite_cpu": round(med["composite_gpu_blend"] / med["composite_cpu_blend"], 3),
    }
    print(f"renderer at {SIZE[0]}x{SIZE[1]} on {fig['renderer']}, {model_id}, {source}; {n} frames timed")
    print(f"  mean uncovered mask: {med.get('mask_px', 0):.0f} px")
    for method in (pp, te):
        stages = "  ".join(f"{k} {med[f'{method}.{k}']:.2f}" for k in
                           ("camera", "texture", "draw", "readback", "masks", "inpaint", "composite"))
        print(f"  {method:8s}: total {med[f'{method}.total']:.2f} ms  ({stages})")
    if "cv2_telea_full_frame" in med:
        print(f"  inpaint: push-pull {med['pushpull.inpaint_with_mask']:.2f} ms, Telea on the box "
              f"{med[f'{te}.inpaint']:.2f} ms, cv2.inpaint Telea full frame {med['cv2_telea_full_frame']:.2f} ms "
              f"-> ratio {fig['ratios']['pushpull_inpaint / cv2_telea_full_frame']:.3f} (target <= 0.1); "
              f"paper {PAPER_INPAINT_MS} ms")
    print(f"  texture + draw + readback: {tex_draw:.2f} ms (paper texture + texcoord + rendering {PAPER_TEXTURE_DRAW_MS} ms)")
    print(f"  composite step: CPU {med['composite_cpu_blend']:.3f} ms, GPU {med['composite_gpu_blend']:.3f} ms")
    print(f"  Lanczos-4 sampling: total {med['lanczos.total']:.2f} ms (texture {med['lanczos.texture']:.2f})")
    if "baseline.total" in med:
        print(f"  baseline compositor ({args.baseline}): total {med['baseline.total']:.2f} ms, this one "
              f"{med[f'{pp}.total']:.2f} ms (same frames, same run)")
        fig["baseline"] = args.baseline
    for name, _, _ in FILL_VARIANTS:
        print(f"  {name:14s}: total {med[f'{name}.total']:.2f} ms (inpaint {med[f'{name}.inpaint']:.2f}, "
              f"plate learning {med.get(f'{name}.plate', 0.0):.2f}); push-pull alone {med[f'{pp}.total']:.2f} ms")
    print(f"  {ATLAS_VARIANT}: total {med[f'{ATLAS_VARIANT}.total']:.2f} ms, wall {med[f'{ATLAS_VARIANT}.wall']:.2f} "
          f"(the atlas updated every {ATLAS_EVERY} frames on its own thread, between frames; drag+plate "
          f"{med['drag+plate.total']:.2f}, "
          f"wall {med['drag+plate.wall']:.2f}) (target <= 10 ms)")
    print(f"  whole renderer stage (push-pull): {med[f'{pp}.total']:.2f} ms (target <= 10 ms)")
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
