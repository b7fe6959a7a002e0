"""Partial regions as vertex masks on the template, drawn fresh for every sample.

A region is the set of template vertices a scan saw; its surface is the faces whose three
vertices are all in it. Every generator returns a raw mask; :meth:`RegionSampler.clean` turns
it into an admissible region (one component, pin-holes closed, a boundary, a sensible area)
or rejects it. With a few fixed region types the part spectra merely identify the type and a
lookup beats any model, so diversity comes from continuous random parameters (centres, radii,
planes, smooth random fields, morphing) rather than from a catalogue.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from app.geometry import eigenpairs, face_areas, mesh_operators
from app.inference import edge_graph, faces_inside
from training.data.template import PART_NAMES, Template

MIN_AREA_FRACTION = 0.1
MAX_AREA_FRACTION = 0.95
PIN_HOLE_AREA_FRACTION = 0.001  # ~15 cm²: smaller holes are scanner drop-outs
MORPH_BASIS = 40  # paper's reference code: first 40 eigenfunctions, thresholds 0.15…0.85


@dataclass(frozen=True)
class Region:
    """An admissible mask and how it was drawn (``kind`` names the generator)."""

    mask: np.ndarray
    kind: str


class RegionSampler:
    """Template-level geometry shared by all generators: areas, graph distances, eigenbasis."""

    def __init__(self, template: Template) -> None:
        self.template = template
        v, f = template.vertices, template.faces
        self.faces = f
        self.face_area = face_areas(v, f)
        self.total_area = float(self.face_area.sum())
        operators = mesh_operators(v, f)
        self.vertex_area = operators.mass.diagonal()
        _, self.basis = eigenpairs(operators, MORPH_BASIS)
        self.graph = edge_graph(v, f)
        self._slot_faces = self._faces_of_graph_slots()
        self.generators: dict[str, Callable[[np.random.Generator], np.ndarray]] = {
            "parts": self.without_parts,
            "ball": self.geodesic_ball,
            "plane": self.plane_cut,
            "holes": self.with_holes,
            "field": self.smooth_field,
        }

    # --- generators: raw masks --------------------------------------------------------
    def without_parts(self, rng: np.random.Generator) -> np.ndarray:
        removed = rng.choice(len(PART_NAMES), size=rng.integers(1, 5), replace=False)
        return ~np.isin(self.template.labels, removed)

    def geodesic_ball(self, rng: np.random.Generator) -> np.ndarray:
        distance = self.distances_from(int(rng.integers(len(self.vertex_area))))
        inside = distance <= self._area_quantile(distance, rng.uniform(0.1, 0.9))
        return ~inside if rng.random() < 0.5 else inside

    def plane_cut(self, rng: np.random.Generator) -> np.ndarray:
        normal = rng.standard_normal(3)
        height = self.template.vertices @ (normal / np.linalg.norm(normal))
        return height >= self._area_quantile(height, rng.uniform(0.05, 0.9))

    def with_holes(self, rng: np.random.Generator) -> np.ndarray:
        base = self.generators[rng.choice(["ball", "plane", "field"])](rng) if rng.random() < 0.5 else None
        mask = np.ones(len(self.vertex_area), bool) if base is None else base.copy()
        for _ in range(rng.integers(2, 6)):
            if not mask.any():
                break
            centre = rng.choice(np.flatnonzero(mask))
            radius = rng.uniform(0.03, 0.09)
            mask &= self.distances_from(int(centre), limit=radius) > radius
        return mask

    def smooth_field(self, rng: np.random.Generator) -> np.ndarray:
        """Superlevel set of a random low-frequency field: shapes no catalogue would list."""
        count = int(rng.integers(3, 16))
        field = self.basis[:, 1 : count + 1] @ (rng.standard_normal(count) / np.arange(1, count + 1))
        return field >= self._area_quantile(field, rng.uniform(0.05, 0.85))

    # --- shaping ----------------------------------------------------------------------
    def morph(self, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Enlarge or shrink: project on the low-frequency basis and threshold in 0.15…0.85."""
        coefficients = self.basis.T @ (self.vertex_area * mask)
        return self.basis @ coefficients >= rng.uniform(0.15, 0.85)

    def clean(self, mask: np.ndarray) -> np.ndarray | None:
        """The admissible region of ``mask``, or None.

        Keeps the largest face-connected component, closes holes smaller than a pin-hole
        (they are not what a region type means), and requires a boundary and an area
        fraction in [``MIN_AREA_FRACTION``, ``MAX_AREA_FRACTION``].
        """
        region = self._largest_component(mask)
        if region is None:
            return None
        outside = self._components(~region)
        for label in np.unique(outside[outside >= 0]):
            if self.vertex_area[outside == label].sum() < PIN_HOLE_AREA_FRACTION * self.total_area:
                region |= outside == label
        fraction = self.area_fraction(region)
        if not MIN_AREA_FRACTION <= fraction <= MAX_AREA_FRACTION:
            return None
        return region

    def sample(self, rng: np.random.Generator, kinds: tuple[str, ...] | None = None) -> Region:
        """A fresh admissible region; morphed half of the time for a continuum of sizes."""
        kinds = kinds or tuple(self.generators)
        while True:
            kind = str(rng.choice(kinds))
            mask = self.generators[kind](rng)
            if rng.random() < 0.5:
                mask = self.morph(mask, rng)
            region = self.clean(mask)
            if region is not None:
                return Region(region, kind)

    # --- measures ---------------------------------------------------------------------
    def area_fraction(self, mask: np.ndarray) -> float:
        inside = faces_inside(mask, self.faces)
        return float(self.face_area[inside].sum() / self.total_area)

    def left_fraction(self, mask: np.ndarray) -> float:
        """Share of the region's area on the body's left (+x): the tie-break of the mirror rule."""
        weights = self.vertex_area * mask
        return float(weights[self.template.vertices[:, 0] > 0].sum() / max(weights.sum(), 1e-12))

    def distances_from(self, vertex: int, limit: float = np.inf) -> np.ndarray:
        """Edge-path distance (m) on the template from one vertex (a cheap geodesic proxy); inf
        beyond ``limit``, where the search stops (a small hole then costs a small search)."""
        return dijkstra(self.graph, indices=vertex, limit=limit)

    def distances_from_set(self, vertices: np.ndarray, limit: float = np.inf) -> np.ndarray:
        """Edge-path distance (m) to the nearest of ``vertices``; inf beyond ``limit``."""
        return dijkstra(self.graph, indices=vertices, min_only=True, limit=limit)

    def is_connected(self, mask: np.ndarray) -> bool:
        """Whether the faces inside ``mask`` form a single component."""
        labels = self._components(mask)
        return len(np.unique(labels[labels >= 0])) == 1

    def _area_quantile(self, values: np.ndarray, q: float) -> float:
        order = np.argsort(values)
        cumulative = np.cumsum(self.vertex_area[order]) / self.vertex_area.sum()
        return float(values[order][np.searchsorted(cumulative, q)])

    def _faces_of_graph_slots(self) -> np.ndarray:
        """(nnz, 2) the (up to two) faces beside each stored edge of ``graph``, -1 for none."""
        graph, n = self.graph, self.graph.shape[0]
        rows = np.repeat(np.arange(n), np.diff(graph.indptr))
        slot_keys = rows * n + graph.indices  # ascending: CSR is row-major with sorted indices
        face = np.repeat(np.arange(len(self.faces)), 6)
        tails = self.faces[:, [0, 1, 1, 2, 2, 0]].ravel()
        heads = self.faces[:, [1, 0, 2, 1, 0, 2]].ravel()
        slots = np.searchsorted(slot_keys, tails * n + heads)
        order = np.argsort(slots, kind="stable")
        slots, face = slots[order], face[order]
        first = np.r_[True, slots[1:] != slots[:-1]]
        beside = np.full((graph.nnz, 2), -1)
        beside[slots[first], 0] = face[first]
        beside[slots[~first], 1] = face[~first]
        return beside

    def _components(self, mask: np.ndarray) -> np.ndarray:
        """Component label per vertex of ``mask`` (-1 outside), joined through its faces.

        Reuses the template graph's structure and switches edges on where a face beside them is
        inside: no sparse matrix is rebuilt per call (regions are cleaned thousands of times).
        """
        inside = np.r_[faces_inside(mask, self.faces), False]  # index -1 reads "no face": False
        on = inside[self._slot_faces[:, 0]] | inside[self._slot_faces[:, 1]]
        # eliminate_zeros works in place: give it copies, not the template graph's own arrays.
        structure = (on.astype(np.float64), self.graph.indices.copy(), self.graph.indptr.copy())
        graph = sp.csr_matrix(structure, shape=self.graph.shape)
        graph.eliminate_zeros()
        # The graph is symmetric, so its strong components are its components, and the strong
        # search skips the transpose an undirected search builds (float64 skips a copy too).
        _, labels = connected_components(graph, directed=True, connection="strong")
        used = np.zeros(len(mask), bool)
        used[self.faces[inside[:-1]].ravel()] = True
        return np.where(used, labels, -1)

    def _largest_component(self, mask: np.ndarray) -> np.ndarray | None:
        labels = self._components(mask)
        if not np.any(labels >= 0):
            return None
        present, inverse = np.unique(labels[labels >= 0], return_inverse=True)
        area = np.bincount(inverse, weights=self.vertex_area[labels >= 0])
        return labels == present[np.argmax(area)]
