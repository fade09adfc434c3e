"""A box-limbed stand-in for the baked people (people.py), with its interface, until they are shipped.

Body frame as people.py: x forward, y left, z up, feet on z = 0. One body whatever the name; two
motions: 'walk' (legs and arms swing, 1.4 m/s) and 'stand'.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# COCO-17 standing joints of a 1.75 m person (x forward, y left, z up)
_REST = np.array([
    [0.08, 0.0, 1.62], [0.07, 0.03, 1.66], [0.07, -0.03, 1.66], [0.02, 0.07, 1.64], [0.02, -0.07, 1.64],
    [0.0, 0.19, 1.45], [0.0, -0.19, 1.45], [0.0, 0.22, 1.17], [0.0, -0.22, 1.17], [0.02, 0.23, 0.92],
    [0.02, -0.23, 0.92], [0.0, 0.11, 0.95], [0.0, -0.11, 0.95], [0.0, 0.11, 0.52], [0.0, -0.11, 0.52],
    [0.0, 0.11, 0.08], [0.0, -0.11, 0.08]])
_BONES = ((5, 7, 0.05), (7, 9, 0.04), (6, 8, 0.05), (8, 10, 0.04), (11, 13, 0.07), (13, 15, 0.055),
          (12, 14, 0.07), (14, 16, 0.055), (5, 12, 0.0), (6, 11, 0.0))
_COLOURS = {0: (0.8, 0.25, 0.2), 1: (0.8, 0.25, 0.2), 2: (0.8, 0.25, 0.2), 3: (0.8, 0.25, 0.2),
            4: (0.2, 0.25, 0.55), 5: (0.2, 0.25, 0.55), 6: (0.2, 0.25, 0.55), 7: (0.2, 0.25, 0.55)}


@dataclass(frozen=True)
class Motion:
    name: str
    fps: float
    duration_s: float
    loop: bool
    speed_mps: float


@dataclass(frozen=True)
class Posed:
    vertices_m: np.ndarray
    joints_m: np.ndarray
    root_m: np.ndarray


def _box(p: np.ndarray, q: np.ndarray, half: float) -> np.ndarray:
    """8 corners of a box of square section 2 half around the segment p -> q."""
    axis = q - p
    a = axis / max(float(np.linalg.norm(axis)), 1e-9)
    u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    ring = np.array([u + v, u - v, -u - v, -u + v]) * half
    return np.vstack([p + ring, q + ring])


_BOX_FACES = np.array([[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7],
                       [0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]], np.int32)


class Person:
    def __init__(self, name: str):
        self.name = name
        self.height_m = 1.75
        n = len(_BONES) + 1
        self.faces = np.vstack([_BOX_FACES + 8 * i for i in range(n)]).astype(np.int32)
        rng = np.random.default_rng(sum(map(ord, name)))
        cols = [np.array(_COLOURS.get(i, (0.25, 0.45, 0.65))) for i in range(len(_BONES))] + [np.array([0.8, 0.6, 0.5])]
        base = np.repeat(np.array(cols, np.float32), 8, axis=0)
        self.colors = np.clip(base * (0.7 + 0.6 * rng.random((len(base), 1))), 0, 1).astype(np.float32)

    def pose(self, motion: Motion, t_s: float) -> Posed:
        j = _REST.copy()
        if motion.name == "walk":
            ph = 2 * math.pi * t_s / 1.1
            for knee, ankle, sign in ((13, 15, 1.0), (14, 16, -1.0)):
                swing = 0.35 * sign * math.sin(ph)
                j[knee, 0] += 0.43 * math.sin(swing)
                j[ankle, 0] += 0.87 * math.sin(swing)
                j[ankle, 2] += 0.05 * max(0.0, sign * math.cos(ph))
            for elbow, wrist, sign in ((7, 9, -1.0), (8, 10, 1.0)):
                swing = 0.3 * sign * math.sin(ph)
                j[elbow, 0] += 0.28 * math.sin(swing)
                j[wrist, 0] += 0.53 * math.sin(swing)
        advance = np.array([motion.speed_mps * t_s, 0.0, 0.0])
        j = j + advance
        boxes = [_box(j[a], j[b], h if h > 0 else 0.12) for a, b, h in _BONES]
        head = j[0] - [0.08, 0.0, 0.0]
        boxes.append(_box(head - [0, 0, 0.14], head + [0, 0, 0.1], 0.09))
        return Posed(vertices_m=np.vstack(boxes).astype(np.float32), joints_m=j,
                     root_m=np.array([advance[0], 0.0, 0.95]))


def load_person(name: str) -> Person:
    return Person(name)


def load_motion(name: str) -> Motion:
    if name not in ("walk", "stand"):
        raise KeyError(name)
    return Motion(name, 30.0, 1.1, True, 1.4 if name == "walk" else 0.0)
