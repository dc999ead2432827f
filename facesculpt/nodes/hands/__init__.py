"""Hands: palm detector + 21-point hand landmarks on onnxruntime, ROI tracking.

    from facesculpt.nodes.hands import HandDetector
    detector = HandDetector()                # networks from `facesculpt setup`
    hands = detector.track(image_bgr)        # [Hand(points (21, 3), score, right, roi, track_id)]

The node (``node.py``, ``facesculpt run hands``) publishes hands/landmarks from camera/image.
"""

from .detector import Hand, HandDetector

__all__ = ["Hand", "HandDetector"]
