"""The synthetic sequences (the unedited input and one ground truth per edit), the lossless
input video, and ``facesculpt process`` run as a user would run it."""

from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .edits import EditSpec, displacement, handle_vertex
from .metrics import changed
from .raster import project, render_textured, visible_vertices
from .scene import Scene


@dataclass
class Sequences:
    """Rendered frames and the geometry the metrics need, per frame i:

    inputs[i] (H, W, 3) uint8 BGR; truth[edit][i] the same frame with the edit; yaw[i] degrees;
    p0[i] (V, 2) px of the unedited vertices, p1[edit][i] of the edited ones; visible[edit][i]
    (V,) bool: vertices seen both before and after the edit; handles[edit]: the SFM vertices
    of the edit's handles; face[i] (H, W) bool: where the head covers the background;
    displacements[edit] (V, 3) mm, the edit's true displacement of the rest vertices; lip: the
    lower lip's centre vertex (iBUG 58), None when the scene's landmarks lack it."""

    inputs: list
    truth: dict
    yaw: np.ndarray
    p0: list
    p1: dict
    visible: dict
    handles: dict
    face: list
    displacements: dict
    lip: int | None = None


_SCENE: Scene | None = None
_DISPLACEMENTS: dict | None = None


def _init(scene: Scene, displacements: dict) -> None:
    global _SCENE, _DISPLACEMENTS
    _SCENE, _DISPLACEMENTS = scene, displacements


def _as_uint8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _render(X: np.ndarray) -> np.ndarray:
    s = _SCENE
    return _as_uint8(render_textured(s.K, X, s.triangles, s.texcoords, s.alpha, s.texture, s.background))


def render_frame(i: int) -> dict:
    """Frame ``i`` unedited and with every edit, with the projected vertices and visibility."""
    s = _SCENE
    size = (s.background.shape[1], s.background.shape[0])
    X0 = s.to_camera(s.rest, i)
    vis0 = visible_vertices(s.K, X0, s.triangles, size, tolerance_mm=3.0)
    out = {"input": _render(X0), "p0": project(s.K, X0)[0], "truth": {}, "p1": {}, "visible": {}}
    for name, D in _DISPLACEMENTS.items():
        X1 = s.to_camera(s.rest + D, i)
        out["truth"][name] = _render(X1)
        out["p1"][name] = project(s.K, X1)[0]
        out["visible"][name] = vis0 & visible_vertices(s.K, X1, s.triangles, size, tolerance_mm=3.0)
    return out


def render_sequences(scene: Scene, specs: list[EditSpec], workers: int | None = None,
                     truth_edit: str = "falloff") -> Sequences:
    """Render ``scene.frames`` frames of the scene, unedited and with each of ``specs`` (their
    displacement of kind ``truth_edit``: :func:`.edits.displacement`)."""
    displacements = {sp.name: displacement(sp, scene.rest, scene.landmarks, truth_edit, scene.model_triangles,
                                           scene.model_vertices) for sp in specs}
    workers = workers or max(1, min(4, len(os.sched_getaffinity(0))))
    if workers > 1:
        with ProcessPoolExecutor(workers, initializer=_init, initargs=(scene, displacements)) as pool:
            frames = list(pool.map(render_frame, range(scene.frames), chunksize=4))
    else:
        _init(scene, displacements)
        frames = [render_frame(i) for i in range(scene.frames)]
    names = [sp.name for sp in specs]
    return Sequences(
        inputs=[f["input"] for f in frames],
        truth={n: [f["truth"][n] for f in frames] for n in names},
        yaw=np.array([scene.pose(i)[0] for i in range(scene.frames)]),
        p0=[f["p0"] for f in frames],
        p1={n: [f["p1"][n] for f in frames] for n in names},
        visible={n: [f["visible"][n] for f in frames] for n in names},
        handles={sp.name: [handle_vertex(h, scene.landmarks) for h in sp.handles] for sp in specs},
        face=[changed(f["input"], scene.background) for f in frames],
        displacements=displacements,
        lip=scene.landmarks.get("58"),
    )


def write_lossless(frames: list, path: Path, fps: int = 25) -> Path:
    """Write BGR uint8 frames as an FFV1 .mkv (lossless, bgr0) with PyAV."""
    import av

    H, W = frames[0].shape[:2]
    with av.open(str(path), "w") as box:
        stream = box.add_stream("ffv1", rate=fps)
        stream.width, stream.height, stream.pix_fmt = W, H, "bgr0"
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(f, format="bgr24")):
                box.mux(packet)
        for packet in stream.encode():
            box.mux(packet)
    return path


def read_video(path: Path, max_frames: int = 0) -> list:
    """Frames of a video as BGR uint8, read with OpenCV (as ``facesculpt process`` reads them)."""
    cap = cv2.VideoCapture(str(path))
    out = []
    while not max_frames or len(out) < max_frames:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    cap.release()
    return out


# Folders of a checkout that install as subpackages of facesculpt (pyproject.toml's package-dir).
MAPPED_PACKAGES = ("nodes", "msgs", "launch")


def importable_checkout(checkout: Path, shim: Path) -> Path:
    """A folder to put first on PYTHONPATH so that ``import facesculpt`` and its mapped
    subpackages (``facesculpt.nodes``, ...) all come from ``checkout`` (a source tree, e.g. an
    older revision): ``shim/facesculpt`` with links to the checkout's ``facesculpt/*`` and its
    top-level ``nodes``, ``msgs`` and ``launch``. Without it only ``facesculpt`` itself would,
    and the installed package's finder would supply the rest from this checkout."""
    checkout = Path(checkout).resolve()
    if all((checkout / "facesculpt" / name).exists() for name in MAPPED_PACKAGES if (checkout / name).is_dir()):
        return checkout
    package = Path(shim) / "facesculpt"
    package.mkdir(parents=True, exist_ok=True)
    for entry in (checkout / "facesculpt").iterdir():
        if not (package / entry.name).exists():
            (package / entry.name).symlink_to(entry)
    for name in MAPPED_PACKAGES:
        if (checkout / name).is_dir() and not (package / name).exists():
            (package / name).symlink_to(checkout / name)
    return Path(shim)


def run_process(video: Path, out_dir: Path, preset: Path, model: str, max_frames: int = 0,
                neutral_frames: int = 30, pythonpath: str = "", data: Path | None = None,
                extra_args: tuple = (), module: str = "facesculpt.cli",
                environment: dict | None = None) -> tuple[list, float]:
    """``facesculpt process VIDEO -o OUT/%05d.png --edits PRESET --model MODEL`` (no --edits when
    ``preset`` is None) in a
    subprocess (with ``pythonpath`` first on its PYTHONPATH when given: another build of
    facesculpt) and FACESCULPT_DATA set to ``data`` when given (where ``sfm`` is read), with
    ``extra_args`` (more process options, e.g. ``--atlas on``) at the end, run as ``python -m
    module`` (another command line in front of facesculpt's, e.g. :mod:`.landmark_oracle`) with
    ``environment`` added: (the frames written, seconds taken). RuntimeError with its stderr on
    failure."""
    import time

    out_dir.mkdir(parents=True, exist_ok=True)
    video, out_dir = Path(video).resolve(), Path(out_dir).resolve()
    cmd = [sys.executable, "-m", module, "process", str(video), "-o", str(out_dir / "%05d.png"),
           "--model", model, "--neutral-frames", str(neutral_frames), "--quiet"]
    if preset is not None:
        cmd += ["--edits", str(Path(preset).resolve())]
    if max_frames:
        cmd += ["--max-frames", str(max_frames)]
    cmd += list(extra_args)
    t0 = time.perf_counter()
    env = {**os.environ, **(environment or {})}
    if data is not None:
        env["FACESCULPT_DATA"] = str(data)
    if pythonpath:
        first = str(importable_checkout(Path(pythonpath), out_dir / "pythonpath"))
        env["PYTHONPATH"] = os.pathsep.join(p for p in (first, env.get("PYTHONPATH", "")) if p)
    # run from out_dir: ``python -m`` puts the working directory first on sys.path, and from a
    # checkout that would import its facesculpt before the one ``pythonpath`` names
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=out_dir)
    took = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    files = sorted(out_dir.glob("*.png"))
    return [cv2.imread(str(f)) for f in files], took
