"""Landmarks: face detector + 468-point face mesh on onnxruntime, ROI tracking, iBUG-68 mapping.

    from facesculpt.nodes.landmarks import LandmarkDetector, to_ibug68
    detector = LandmarkDetector()            # networks from `facesculpt setup`
    faces = detector.track(image_bgr)        # [Face(points (468, 3), score, roi)], [] if none
    ibug = to_ibug68(faces[0].points)        # (68, 2) in iBUG order

The node (``node.py``, ``facesculpt run landmarks``) publishes face/landmarks from camera/image.
"""

from .detector import Face, LandmarkDetector
from .ibug68 import IBUG68_FROM_MESH, normalised_mean_error, to_ibug68

__all__ = ["Face", "LandmarkDetector", "IBUG68_FROM_MESH", "normalised_mean_error", "to_ibug68"]
