"""The deformer's options (the live deformer node's and :class:`.edits.EditStack`'s), declared once
with their defaults, units, ranges and help (:func:`facesculpt.options.option`); the deformer
node's parameters derive from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from facesculpt.options import option

from .solve_mesh import MIN_SOLVE_VERTICES, MIN_SOLVE_VERTICES_RANGE

# A handle grips the skin within this share of its edit's ROI radius (same metric), which moves
# with it rigidly. 0, the default, is the paper's single-vertex handle: ARAP pulling one vertex of
# a dense mesh makes a cusp (the vertex moves, its neighbours lag), yet that is the deformation the
# paper describes, and a grip makes another, larger nose or chin (docs/results/paper-arap.md).
GRIP = 0.0
GRIP_RANGE = (0.0, 0.5)
# An edit has settled when no vertex moves by more than this share of the mesh's bounding-box
# diagonal in an iteration (the deformer node's default ``tolerance``, which its idle rounds reach).
SETTLE_TOLERANCE = 1e-5
ROI_METRICS = ("geodesic", "euclidean")


@dataclass(frozen=True)
class DeformerOptions:
    """How edits are made and solved: the ROI of a new handle, its grip, the solve mesh, and the
    live solve's iterations (a drag update's; the idle rounds go on until ``tolerance``)."""

    roi_radius: float = option(40.0, "default ROI of a new handle, on the neutral mesh", "mm", range=(0.1, 1000.0))
    roi_metric: str = option("geodesic", "distance the ROI radius is measured in", choices=ROI_METRICS)
    grip: float = option(GRIP, "share of a handle's ROI radius around it that moves rigidly with it (0: the "
                               "handle vertex alone, as in the paper)", range=GRIP_RANGE)
    min_solve_vertices: int = option(MIN_SOLVE_VERTICES, "a model mesh with fewer vertices is solved on its "
                                                         "refinement with at least as many, its holes closed (0: "
                                                         "always on the model's own mesh)", "vertices",
                                     range=MIN_SOLVE_VERTICES_RANGE)
    iterations: int = option(4, "ARAP local/global iterations per solve of a drag update (Anderson-accelerated)",
                             range=(1, 100))
    tolerance: float = option(SETTLE_TOLERANCE, "stop early below this per-iteration motion, x bounding-box "
                                                "diagonal (0: never)", range=(0.0, 1.0))
    acceleration: str = option("anderson", "how a solve converges: anderson (accelerated) or none (plain "
                                           "local/global)", choices=("anderson", "none"))
    clamp_weights: bool = option(True, "clamp obtuse-angle cotangents at 0")
