"""Every option of the compositor (:class:`.compositor.Compositor`), declared once with its
default, unit, valid range and help (:func:`facesculpt.options.option`). The renderer node's
parameters and the in-process pipeline's ``render=`` derive from these fields; a node value of
``auto`` (:mod:`.frame_size_defaults`) resolves to one of them by the frame's size."""

from __future__ import annotations

from dataclasses import dataclass

from facesculpt.options import option

from .inpaint import FILL_METHODS
from .subdivision import MAX_FINE_EDGE_PX
from .warp import INTERPOLATIONS

#: A shape edit's motion reaches this far past the fitted outline (share of the face's size).
OUTLINE_BAND = 0.05


@dataclass(frozen=True)
class CompositorOptions:
    """How the compositor renders a deformed face into the frame (the frame size and the GL
    context are given separately)."""

    inpaint: str = option("drag", "fill of the background the deformed face uncovers where it was never seen: drag "
                                  "(the background beside the face carried in by its motion), pushpull (smooth), "
                                  "telea / ns (OpenCV inpainting), patch (background copied in from nearby, seams "
                                  "corrected)", choices=FILL_METHODS)
    feather_px: float = option(3.0, "least width of the soft edge inside the deformed outline (it grows with the "
                                    "face's size; 0: a hard edge)", "px", range=(0.0, 100.0))
    dilate_px: int = option(2, "growth of the region to inpaint", "px", range=(0, 100))
    telea_radius: float = option(3.0, "neighbourhood of the telea / ns inpainting", "px", range=(0.5, 100.0))
    interpolation: str = option("sinc", "kernel the frame is resampled with where the face moved: sinc (a long "
                                        "windowed sinc: keeps the skin's finest detail), cubic (faster, softer), "
                                        "lanczos (Lanczos-4), linear", choices=INTERPOLATIONS)
    subdivision: int | None = option(None, "Loop subdivision levels of the render mesh", "levels", range=(0, 3),
                                     none="per frame, as few as make its edges max_fine_edge_px long on screen")
    max_fine_edge_px: float | None = option(MAX_FINE_EDGE_PX, "longest edge of the subdivided mesh on screen",
                                            "px", range=(0.5, 64.0), none="as many levels as 16384 triangles allow")
    atlas: bool = option(False, "keep a texture memory of the face (UV atlas) and take colours from it where the "
                                "frame sees the edited surface badly (stretched, hidden)")
    atlas_size: int = option(256, "atlas texels a side", "texels", range=(32, 2048))
    atlas_every: int = option(1, "update the atlas every N frames (the frames between only read it)", "frames",
                              range=(1, 1000))
    atlas_blend: bool = option(True, "blend colours from the atlas (False: learn it only, e.g. to save it)")
    atlas_thread: bool = option(False, "update the atlas on a thread of its own (skipped while the last update "
                                       "runs: for live use, not deterministic)")
    plate: bool = option(False, "keep a background plate (the background seen behind the face in other frames, "
                                "registered when the camera moves) and take uncovered pixels from it where known")
    plate_max_age: int = option(150, "background plate: frames after which a pixel's estimate is no longer used",
                                "frames", range=(1, 100000))
    plate_register: bool = option(True, "background plate: follow the camera's motion")
    keyframes: bool = option(False, "keep views of the face at other poses and render turned surface from the "
                                    "closest one where it sees it better than the frame")
    mend_silhouette: bool = option(False, "pose edits: colour the turned face's pixels that the input saw only at "
                                          "its outline (stretched) from the well-seen face beside them (removes a "
                                          "pale arc along a near cheek, but leaves a hard cut-out edge there)")
    outline_band: float = option(OUTLINE_BAND, "how far past the fitted outline a shape edit's motion is carried, "
                                               "fading out (a real outline the fit lies inside moves with the face; "
                                               "0: not at all)", "share of the face's size", range=(0.0, 0.5))
