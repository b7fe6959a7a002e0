"""Small meshes built in code, each with a known spectrum or a known relation to another."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay

from app.geometry.shapes import Mesh
from harness.postgres import ThrowawayPostgres


def disk(radius: float = 1.0, rings: int = 30) -> Mesh:
    """Flat disk from concentric rings of evenly spaced points, Delaunay-triangulated."""
    points = [np.zeros((1, 2))]
    for i in range(1, rings + 1):
        r = radius * i / rings
        count = 6 * i
        theta = 2 * np.pi * (np.arange(count) + 0.5 * (i % 2)) / count
        points.append(np.column_stack([r * np.cos(theta), r * np.sin(theta)]))
    xy = np.concatenate(points)
    faces = Delaunay(xy).simplices.astype(np.int64)
    return Mesh(np.column_stack([xy, np.zeros(len(xy))]), faces)


def grid(width: float, height: float, nx: int, ny: int) -> Mesh:
    """Rectangle [0, width] × [0, height] split into right triangles."""
    x, y = np.meshgrid(np.linspace(0, width, nx + 1), np.linspace(0, height, ny + 1), indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    index = np.arange(x.size).reshape(nx + 1, ny + 1)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(vertices, faces.astype(np.int64))


def sphere(subdivisions: int = 4) -> Mesh:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    return Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64))


def bumpy_patch(seed: int = 0, n: int = 900) -> Mesh:
    """An irregular, curved surface with boundary: random points, a smooth bump, no symmetry."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1, 1, size=(n, 2))
    xy = xy[np.linalg.norm(xy, axis=1) < 1]
    faces = Delaunay(xy).simplices.astype(np.int64)
    z = 0.3 * np.exp(-3 * ((xy[:, 0] - 0.2) ** 2 + xy[:, 1] ** 2)) + 0.1 * xy[:, 0] * xy[:, 1]
    return Mesh(np.column_stack([xy, z]), faces)


@pytest.fixture(scope="session")
def patch() -> Mesh:
    return bumpy_patch()


@pytest.fixture(scope="session")
def postgres_url():
    """A throw-away PostgreSQL server's URL, shared by every folder; skipped where none can start."""
    try:
        server = ThrowawayPostgres()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    server.start()
    yield server.url
    server.remove()
