"""The README's realism picture: input | result | close-ups of the same edit before and after.

The face is the install's embedded photo (scikit-image's astronaut.png, NASA, public domain),
framed as ``facesculpt demo`` frames it; the edits are shipped presets. "After" is the
facesculpt this script belongs to; "before" is an older checkout (``--before DIR``, a source
tree such as ``git worktree add /tmp/before 37891d3~1``), each rendered in a child process of
its own so that the two never share an import.

Run: ``python -m benchmarks.readme_figure --before DIR [--edits chin,nose_longer] [--model
facemesh] [-o docs/images/realism.jpg]``. Needs ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.sequences import importable_checkout

REPO = Path(__file__).resolve().parent.parent


def embedded_frame() -> np.ndarray:
    """The demo's framing of the embedded photo: (480, 640, 3) uint8 BGR."""
    from facesculpt.nodes.camera.sources import embedded_source

    return embedded_source().image.copy()


def render(out: Path, edits: list[str], model: str) -> None:
    """Child: the frame with ``edits`` (shipped preset names) composited, written to ``out``,
    and the edit's bounding box (x0, y0, x1, y1) to ``out``.box."""
    from facesculpt.app.pipeline import Pipeline, read_preset
    from facesculpt.nodes.deformer.preset_format import merge_presets

    frame = embedded_frame()
    with Pipeline(model) as pipeline:
        pipeline.calibrate([frame] * 30, 30.0)
        pipeline.set_edits(merge_presets([read_preset(e) for e in edits]))
        result = pipeline.process(frame, 1.0)
    cv2.imwrite(str(out), result.image)
    changed = np.any(result.image != frame, axis=2)
    ys, xs = np.nonzero(changed)
    box = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) if xs.size else (0, 0, 0, 0)
    Path(f"{out}.box").write_text(" ".join(str(int(v)) for v in box))


def run_child(checkout: Path | None, out: Path, edits: list[str], model: str, scratch: Path) -> tuple:
    """Render with the facesculpt of ``checkout`` (None: this one) in a subprocess; the box."""
    import os

    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])  # where ``benchmarks`` imports from
    first = [str(importable_checkout(checkout, scratch / "pythonpath"))] if checkout is not None else []
    env["PYTHONPATH"] = os.pathsep.join([*first, root])
    cmd = [sys.executable, "-m", "benchmarks.readme_figure", "--render", str(out), "--edits", ",".join(edits),
           "--model", model]
    # run from scratch, so that the checkout's facesculpt (first on PYTHONPATH) is the one imported
    done = subprocess.run(cmd, env=env, cwd=scratch, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"rendering with {checkout or 'this checkout'} failed: {done.stderr.strip()[-1500:]}")
    return tuple(int(v) for v in Path(f"{out}.box").read_text().split())


def labelled(img: np.ndarray, text: str) -> np.ndarray:
    strip = np.full((26, img.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, text, (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([strip, img])


def figure(frame: np.ndarray, before: np.ndarray, after: np.ndarray, box: tuple, height: int = 300) -> np.ndarray:
    """input | result | before (close-up) | after (close-up), one row of equal heights."""
    x0, y0, x1, y1 = box
    side = max(x1 - x0, y1 - y0, 40) + 16
    cx, cy = (x0 + x1) // 2, (y0 + y1) // 2
    H, W = frame.shape[:2]
    bx = int(np.clip(cx - side // 2, 0, W - side))
    by = int(np.clip(cy - side // 2, 0, H - side))

    def close(img):
        c = img[by:by + side, bx:bx + side]
        return cv2.resize(c, (height, height), interpolation=cv2.INTER_NEAREST)

    def whole(img):
        return cv2.resize(img, (int(round(W * height / H)), height), interpolation=cv2.INTER_AREA)

    panels = [labelled(whole(frame), "input"), labelled(whole(after), "result"),
              labelled(close(before), "close-up: before"), labelled(close(after), "close-up: now")]
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    row = [p for panel in panels for p in (panel, gap)][:-1]
    return np.hstack(row)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--before", type=Path, help="an older facesculpt source tree for the 'before' close-up")
    p.add_argument("--edits", default="chin,nose_longer", help="shipped presets, comma-separated")
    p.add_argument("--model", default="facemesh")
    p.add_argument("-o", "--output", type=Path, default=REPO / "docs" / "images" / "realism.jpg")
    p.add_argument("--render", type=Path, help=argparse.SUPPRESS)  # the child's job
    a = p.parse_args(argv)
    edits = [e for e in a.edits.split(",") if e]
    if a.render:
        render(a.render, edits, a.model)
        return 0
    if a.before is None:
        p.error("--before DIR is needed (an older checkout to compare with)")
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        box = run_child(None, scratch / "after.png", edits, a.model, scratch)
        old_box = run_child(a.before, scratch / "before.png", edits, a.model, scratch)
        after, before = cv2.imread(str(scratch / "after.png")), cv2.imread(str(scratch / "before.png"))
    union = (min(box[0], old_box[0]), min(box[1], old_box[1]), max(box[2], old_box[2]), max(box[3], old_box[3]))
    a.output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.output), figure(embedded_frame(), before, after, union), [cv2.IMWRITE_JPEG_QUALITY, 92])
    print(f"wrote {a.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
