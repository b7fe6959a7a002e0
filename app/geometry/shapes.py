"""Plain containers for parsed shapes: numpy arrays in metres, nothing else."""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: ``vertices`` (n, 3) float64 in metres, ``faces`` (m, 3) int64."""

    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class PointCloud:
    """Points (n, 3) float64 in metres; ``boundary`` flags boundary points when the file says so."""

    points: np.ndarray
    boundary: np.ndarray | None = None


Shape = Mesh | PointCloud
