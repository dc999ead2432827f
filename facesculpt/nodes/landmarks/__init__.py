"""Landmarks: face detector + 468-point face mesh on onnxruntime, ROI tracking.

    from facesculpt.geometry import to_ibug68
    from facesculpt.nodes.landmarks import LandmarkDetector
    detector = LandmarkDetector()            # networks from `facesculpt setup`
    faces = detector.track(image_bgr)        # [Face(points (468, 3), score, roi)], [] if none
    ibug = to_ibug68(faces[0].points)        # (68, 2) in iBUG order

The node (``node.py``, ``facesculpt run landmarks``) publishes face/landmarks from camera/image.
"""

from .detector import Face, LandmarkDetector

__all__ = ["Face", "LandmarkDetector"]
