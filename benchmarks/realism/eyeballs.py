"""Eyeballs for the synthetic head (the gaze benchmark): a sphere per eye with sclera, a striped
iris and a pupil, ray-cast into the eye's opening, turned to known gaze angles, the lids following.

The scene's head (:mod:`.scene`, the Surrey Face Model) has no eyes of its own (its texture shows
the photo's eyes painted on the closed surface). Here each eye's opening is a smooth closed curve
through the model's six iBUG lid vertices (37-42, 43-48); inside it the eyeball is drawn instead
of the surface, shaded, with a soft shadow under the upper lid and a highlight of a light beside
the camera. The eyeball is placed by anatomy, from the scene's own surface and independently of
the estimator: its front (the cornea's apex) 1 mm in front of the centroid of the lid vertices
(the closed surface over the eye), along the head's forward axis; radius and iris radius per
person from :func:`eye_anatomy`. The upper lid follows the eye's pitch (raised by 0.6 and the lower
by 0.25 of the iris centre's vertical travel), as lids do.

Model space is the SFM's (mm, x to the subject's left, y up, z out of the face); camera space
OpenCV's. Eye 0 is the right eye.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .raster import project

LID_NAMES = (("37", "38", "39", "40", "41", "42"), ("43", "44", "45", "46", "47", "48"))
#: Which of the six lid points are on the upper lid.
UPPER = (1, 2)
LOWER = (4, 5)
PUPIL_MM = 2.0
APEX_AHEAD_MM = 1.0
SS = 4


@dataclass
class Eyes:
    """One person's eyes: lid vertices (2, 6) of the scene's rest mesh, eyeball centres (2, 3)
    model mm, eyeball radius (mm), iris radius (mm), iris colour BGR (3,)."""

    lids: np.ndarray
    centres: np.ndarray
    radius: float
    iris_radius: float
    iris_colour: np.ndarray


def eye_anatomy(scene, seed: int) -> Eyes:
    """The eyes of the scene's person: radius 11.5-12.5 mm, iris radius 5.7-6.2 mm, drawn from
    ``seed``; centres behind the lids' centroid so the cornea's apex is ``APEX_AHEAD_MM`` ahead."""
    rng = np.random.default_rng(seed + 101)
    radius = float(rng.uniform(11.5, 12.5))
    iris = float(rng.uniform(5.7, 6.2))
    lids = np.array([[scene.landmarks[n] for n in eye] for eye in LID_NAMES])
    centroid = scene.rest[lids].mean(axis=1)
    centres = centroid - np.array([0.0, 0.0, radius - APEX_AHEAD_MM])
    colour = np.array(rng.choice([(40, 70, 110), (120, 100, 60), (60, 110, 90)]), np.float64)
    return Eyes(lids=lids, centres=centres, radius=radius, iris_radius=iris, iris_colour=colour)


def eye_rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """(3, 3) model-space rotation of an eye looking ``yaw_deg`` toward the subject's left and
    ``pitch_deg`` up from straight out of the face."""
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), np.sin(b)], [0, -np.sin(b), np.cos(b)]])  # +z turns up
    return Ry @ Rx


def _opening(points: np.ndarray, samples: int = 10) -> np.ndarray:
    """A closed Catmull-Rom curve (6 * samples, 3) through six points (6, 3) in order."""
    p = np.asarray(points, np.float64)
    out = []
    for k in range(len(p)):
        p0, p1, p2, p3 = p[k - 1], p[k], p[(k + 1) % len(p)], p[(k + 2) % len(p)]
        for s in np.linspace(0.0, 1.0, samples, endpoint=False):
            out.append(0.5 * ((2 * p1) + (-p0 + p2) * s + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s * s
                              + (-p0 + 3 * p1 - 3 * p2 + p3) * s ** 3))
    return np.array(out)


def _shade(hit_eye: np.ndarray, normal_cam: np.ndarray, view: np.ndarray, eyes: Eyes) -> np.ndarray:
    """Colours (N, 3) BGR 0-255 of eyeball points: ``hit_eye`` (N, 3) on the unit sphere in the
    eye's own frame (+z its axis), their camera-space normals and unit directions to the camera."""
    rho = np.hypot(hit_eye[:, 0], hit_eye[:, 1]) * eyes.radius  # distance from the axis, mm
    front = hit_eye[:, 2] > 0
    angle = np.arctan2(hit_eye[:, 1], hit_eye[:, 0])
    colour = np.tile(np.array([215.0, 222.0, 232.0]), (len(hit_eye), 1))
    colour *= (1.0 - 0.15 * np.clip((rho / eyes.radius) ** 2, 0, 1))[:, None] * np.array([1.0, 0.97, 1.0])
    iris = front & (rho < eyes.iris_radius)
    stripes = 0.75 + 0.25 * np.sin(angle * 37.0) * np.sin(angle * 11.0 + rho * 3.0)
    ring = np.clip((rho - 0.85 * eyes.iris_radius) / (0.15 * eyes.iris_radius), 0, 1)
    colour[iris] = (eyes.iris_colour * stripes[:, None] * (1.0 - 0.55 * ring[:, None]))[iris]
    colour[front & (rho < PUPIL_MM)] = 18.0
    lambert = np.clip(np.einsum("nk,nk->n", normal_cam, view), 0.0, 1.0)
    colour *= (0.55 + 0.45 * lambert)[:, None]
    colour += 255.0 * (lambert > 0.997)[:, None] * 0.8
    return np.clip(colour, 0, 255)


def draw_eyes(image: np.ndarray, scene, eyes: Eyes, R: np.ndarray, to_camera, gaze: np.ndarray) -> np.ndarray:
    """The rendered head ``image`` (H, W, 3) float32 with both eyeballs drawn into their openings.
    R (3, 3): the head's model-to-camera rotation; to_camera: model mm (N, 3) -> camera mm;
    gaze (2, 2): each eye's yaw, pitch (degrees) in the head."""
    out = image.copy()
    H, W = out.shape[:2]
    for e in (0, 1):
        rot = eye_rotation(*gaze[e])
        axis = rot @ np.array([0.0, 0.0, 1.0])
        lid = scene.rest[eyes.lids[e]].copy()
        rise = eyes.radius * axis[1]
        lid[list(UPPER), 1] += 0.6 * rise
        lid[list(LOWER), 1] += 0.25 * rise
        curve_px = project(scene.K, to_camera(_opening(lid)))[0]
        x0, y0 = np.floor(curve_px.min(axis=0)).astype(int) - 2
        x1, y1 = np.ceil(curve_px.max(axis=0)).astype(int) + 3
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if x1 <= x0 or y1 <= y0:
            continue
        w, h = x1 - x0, y1 - y0
        mask = np.zeros((h * SS, w * SS), np.uint8)
        cv2.fillPoly(mask, [np.round((curve_px - [x0, y0]) * SS * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
        shadow = cv2.distanceTransform((mask > 0).astype(np.uint8), cv2.DIST_L2, 3) / SS  # px from the lid
        ys, xs = np.mgrid[0:h * SS, 0:w * SS]
        px = np.column_stack([x0 + (xs.ravel() + 0.5) / SS, y0 + (ys.ravel() + 0.5) / SS])
        rays = np.column_stack([(px - scene.K[:2, 2]) / np.diag(scene.K)[:2], np.ones(len(px))])
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        centre = to_camera(eyes.centres[e][None])[0]
        r = eyes.radius
        b = rays @ centre
        disc = b * b - (centre @ centre - r * r)
        hit = np.sqrt(np.maximum(disc, 0.0))
        points = rays * (b - hit)[:, None]
        normals = (points - centre) / r
        eye_frame = normals @ R @ rot  # camera -> model -> the eye's own frame
        colour = _shade(eye_frame, normals, -rays, eyes)
        colour[disc < 0] = 60.0
        upper_edge = np.clip(shadow.ravel() / 3.0, 0.0, 1.0)
        colour *= (0.6 + 0.4 * upper_edge)[:, None]
        a = (mask.astype(np.float32) / 255.0).reshape(h, SS, w, SS).mean(axis=(1, 3))
        c = colour.reshape(h, SS, w, SS, 3).mean(axis=(1, 3)).astype(np.float32)
        out[y0:y1, x0:x1] = a[..., None] * c + (1.0 - a[..., None]) * out[y0:y1, x0:x1]
    return out
