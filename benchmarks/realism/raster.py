"""The benchmark's reference rasteriser: :mod:`facesculpt.geometry.raster` (it moved into the package
so that `facesculpt model calibrate` can render its calibration sequences); re-exported here for
the benchmark's parts."""

from facesculpt.geometry.raster import (  # noqa: F401 (re-exported)
    Fragments,
    project,
    project_pixels,
    rasterise,
    render_textured,
    visible_vertices,
)
