"""Views glued through their own meshes: where the union's spectrum is solved when every view
is a mesh.

A point-cloud Laplacian of the fused views' points is a few per cent off each view's own mesh
Laplacian (more on an irregular re-meshing), and that error is the union's wherever the views
overlap little; glued, each view keeps its own triangles. A later view's triangles that lie
wholly on an earlier view's inside go (the earlier view's stand there); each point a later view
loses to an earlier one (a duplicate, a point on its inside, or a loose end facing the earlier
view's across a seam) is welded to the nearest point of another view, so the triangles it had
stitch the views together. A pin-hole between views, capped, is a fan of triangles around its
centre. Measured against the exact union on anny sessions:
``docs/decisions/045-views-glued-through-their-meshes.md``.
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from app.geometry.laplacian import mesh_operators
from app.geometry.spectrum import eigenpairs
from app.geometry.topology import component_areas, drop_unreferenced, referenced
from app.geometry.validate import surface_faces

WELD_CANDIDATES = 8  # nearest cloud points searched for one of another view to weld onto
MIN_COMPONENT_SHARE = 0.01  # of the glued area: a piece smaller than this, left by the seams, is no surface


@dataclass(frozen=True)
class Seams:
    """One view's share of the glue, its arrays over its own points: ``kept`` in the cloud (the
    cloud's points are the kept points, view after view); ``under`` an earlier view's inside (a
    triangle of these alone goes); ``welded`` joined to an earlier view (not kept, or a seam's
    loose end)."""

    faces: np.ndarray
    kept: np.ndarray
    under: np.ndarray
    welded: np.ndarray


def welded_faces(points: list[np.ndarray], seams: list[Seams], cloud: cKDTree, owner: np.ndarray) -> np.ndarray:
    """(m, 3) the views' triangles over the cloud's points (its k-d tree ``cloud``), each once.
    ``points``: each view's points; ``owner``: the view each cloud point comes from (−1 for
    none)."""
    offset, out = 0, []
    for index, (own, seam) in enumerate(zip(points, seams, strict=True)):
        into = np.full(len(own), -1)
        into[seam.kept] = offset + np.arange(int(seam.kept.sum()))
        offset += int(seam.kept.sum())
        moved = np.flatnonzero(seam.welded)
        if len(moved):
            into[moved] = _nearest_of_another(cloud, owner, own[moved], index)
        out.append(into[seam.faces[~seam.under[seam.faces].all(axis=1)]])
    return surface_faces(np.concatenate(out))  # welding collapses some, and gives others twice


def _nearest_of_another(tree: cKDTree, owner: np.ndarray, points: np.ndarray, view: int) -> np.ndarray:
    """For each of a view's ``points``, the nearest cloud point another view put there (the
    nearest cloud point where none is among the WELD_CANDIDATES nearest)."""
    _, nearest = tree.query(points, k=min(WELD_CANDIDATES, tree.n))
    nearest = nearest.reshape(len(points), -1)
    other = owner[nearest] != view
    pick = np.where(other.any(axis=1), other.argmax(axis=1), 0)
    return nearest[np.arange(len(points)), pick]


def cap_fans(cloud: np.ndarray, rings: list[np.ndarray], centres: np.ndarray, first: int) -> np.ndarray:
    """(m, 3) a fan of triangles capping each pin-hole: the cloud points ``rings[h]`` around it,
    in turn about its centre (cloud point ``first + h``)."""
    fans = [np.empty((0, 3), np.int64)]
    for hole, ring in enumerate(rings):
        ring = np.unique(ring)
        if len(ring) < 3:
            continue
        spoke = cloud[ring] - centres[hole]
        _, _, axes = np.linalg.svd(spoke, full_matrices=False)  # the hole's plane: its two widest axes
        ring = ring[np.argsort(np.arctan2(spoke @ axes[1], spoke @ axes[0]))]
        fans.append(np.column_stack([ring, np.roll(ring, -1), np.full(len(ring), first + hole)]))
    return np.concatenate(fans)


def glued_spectrum(cloud: np.ndarray, faces: np.ndarray, boundary: np.ndarray, k: int) -> np.ndarray:
    """The first ``k`` eigenvalues of the glued surface: the cloud's points its triangles use,
    less the specks the seams leave (pieces under MIN_COMPONENT_SHARE of the area); Dirichlet on
    ``boundary``, or closed where none is left."""
    faces = _without_specks(cloud, faces)
    used = referenced(faces, len(cloud))
    operators = mesh_operators(*drop_unreferenced(cloud, faces))
    fixed = boundary[used]
    values, _ = eigenpairs(operators, k, fixed if fixed.any() else None, vectors=False)
    return np.asarray(values)


def _without_specks(cloud: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` less the connected pieces holding under MIN_COMPONENT_SHARE of their area: a
    piece that small is what a seam leaves, and one with no boundary would add a zero
    eigenvalue; the union's real pieces (views that do not touch) stay."""
    piece, area = component_areas(cloud, faces)
    return faces[area[piece] >= MIN_COMPONENT_SHARE * area.sum()]
