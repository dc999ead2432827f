"""Geometry that several rooms share: pure functions, arrays in and arrays out (one per file).

* :mod:`.projection`: camera-space points to pixels and pixels to rays, under the graph's
  two camera conventions (perspective with intrinsics K, scaled orthographic), and through a
  general (3, 4) projection matrix;
* :mod:`.boundary_loops`: the boundary loops of a triangle mesh;
* :mod:`.merge_deformation`: the paper's Eq. 5, the user's edit merged into a fitted mesh;
* :mod:`.ibug68`: the 468 face-mesh points in the iBUG-68 landmark scheme;
* :mod:`.axes_velocity`: joystick axes to a model-space velocity (and its parameters);
* :mod:`.hand_regions`: the 21 hand joints by name, a hand's size, the region hands cover;
* :mod:`.point_bounds`: the bounding box and the centroid of a point set;
* :mod:`.roi_tracker`, :mod:`.detector_options`: the face and hand detectors' track-and-redetect
  loop and their options.

Nodes import from here instead of from each other (docs/architecture.md "Layers").
"""

from facesculpt.geometry.axes_velocity import axes_velocity
from facesculpt.geometry.boundary_loops import boundary_loops
from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH, normalised_mean_error, to_ibug68
from facesculpt.geometry.merge_deformation import merge_deformation
from facesculpt.geometry.point_bounds import centroid, point_bounds
from facesculpt.geometry.projection import (
    PROJECTIONS,
    pixel_ray,
    project,
    project_orthographic,
    project_with_matrix,
)

__all__ = [
    "IBUG68_FROM_MESH",
    "PROJECTIONS",
    "axes_velocity",
    "boundary_loops",
    "centroid",
    "merge_deformation",
    "normalised_mean_error",
    "pixel_ray",
    "point_bounds",
    "project",
    "project_orthographic",
    "project_with_matrix",
    "to_ibug68",
]
