"""Spectra of (shape, region) pairs through ``app.geometry``, the code that serves requests.

A region of a posed body is the faces whose three vertices are all in its template mask; the
submesh goes through exactly the validation, pin-hole filling and solver of the service, so
training data and served requests share one spectrum definition.
"""

from dataclasses import dataclass

import fast_simplification
import numpy as np

from app.geometry import (
    GeometryError,
    Mesh,
    PointCloud,
    SpectrumOptions,
    boundary_vertex_mask,
    cloud_spectrum,
    drop_unreferenced,
    mesh_spectrum,
)
from app.inference import faces_inside

MESH, REMESHED, CLOUD = "mesh", "remeshed", "cloud"
VARIANTS = (MESH, REMESHED, CLOUD)
REMESH_REDUCTION = 0.3  # the paper's re-meshing: 30 % of the vertices removed


@dataclass(frozen=True)
class SpectrumTask:
    shape: int
    mask: int
    variant: str


def region_mesh(vertices: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> Mesh:
    """The submesh of the faces inside ``mask`` (the whole closed body for a full mask)."""
    inside = faces[faces_inside(mask, faces)]
    return Mesh(*drop_unreferenced(vertices, inside))


def remeshed(mesh: Mesh) -> Mesh:
    """Quadric edge collapse removing ~30 % of the vertices, boundary kept in place."""
    v, f = fast_simplification.simplify(
        mesh.vertices.astype(np.float64), mesh.faces.astype(np.int64), target_reduction=REMESH_REDUCTION
    )
    return Mesh(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))


def as_point_cloud(mesh: Mesh) -> PointCloud:
    """The region's vertices with its boundary flagged, as a scanner's cloud would arrive."""
    boundary = boundary_vertex_mask(mesh.faces, len(mesh.vertices))
    return PointCloud(mesh.vertices, boundary if boundary.any() else None)


def task_spectrum(
    vertices: np.ndarray, faces: np.ndarray, mask: np.ndarray, variant: str, k: int, *, cap_holes: bool = False
) -> np.ndarray:
    """k eigenvalues of one task, NaN where the region cannot be solved (counted in the card);
    ``cap_holes``: the region's holes capped as the service's ``cap_holes=true`` caps an upload's."""
    mesh = region_mesh(vertices, faces, mask)
    options = SpectrumOptions(k=k, cap_holes=cap_holes)
    try:
        if variant == CLOUD:
            cloud = as_point_cloud(mesh)
            options = SpectrumOptions(k=k, closed=cloud.boundary is None)
            return np.array(cloud_spectrum(cloud, options).eigenvalues)
        if variant == REMESHED:
            mesh = remeshed(mesh)
        return np.array(mesh_spectrum(mesh, options).eigenvalues)
    except GeometryError:
        return np.full(k, np.nan)
