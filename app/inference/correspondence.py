"""The correspondence model as served: an uploaded part's vertices placed on the template, the
region of the template they reach, and the overlap of two parts read on the template.

Twenty eigenvalues do not say where a part lies or how much two parts overlap; its geometry
does. The network (:data:`app.contract.CORRESPONDENCE_FILE`, trained by
``training.correspondence``) places every vertex on the template's rest pose, so two parts
scanned in different poses, frames or meshings are compared where they lie on one body, with
no registration. Optional: the service serves everything else without it.
"""

import base64
import binascii
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from app.contract import CORRESPONDENCE_INPUTS
from app.core.errors import InputError
from app.geometry.descriptors import PartInputs
from app.inference.template import RegionBoundaries, Template, edge_graph

# A template vertex is reached when a placed vertex lies within REACH_M of it, and the reached
# vertices are closed by CLOSING_M along the template's edges (dilate, then erode), filling the
# gaps a coarse part leaves without growing the outline. Places bunch and sit a little inside
# the surface (a weighted centre of patch centres lies on their chords): a template vertex's own
# nearest place misses ~30 % of a region. Chosen on 60 training parts (region IoU 0.58 by nearest
# vertex; reach 1.5 / 2 / 3 / 4 cm, closed: 0.66 / 0.75 / 0.79 / 0.77), not on test parts.
REACH_M = 0.03
CLOSING_M = 0.03


REGION_TOKEN_PREFIX = "region1:"


class InvalidRegion(InputError):
    """A region token that is not one of this template's regions."""

    slug = "invalid-region"
    title = "Invalid region"


def region_token(region: np.ndarray) -> str:
    """A template region (V,) bool as text a client keeps and sends back (``regions``): its
    vertices bit-packed, base64 (~2 KB for the 12 167-vertex template)."""
    return REGION_TOKEN_PREFIX + base64.b64encode(np.packbits(region).tobytes()).decode("ascii")


def region_from_token(token: object, vertices: int, name: str) -> np.ndarray:
    """(vertices,) bool from :func:`region_token`'s text; InvalidRegion naming ``name`` when it
    is not a token of a template of this many vertices, or holds no vertex."""
    if not isinstance(token, str) or not token.startswith(REGION_TOKEN_PREFIX):
        raise InvalidRegion(f"{name} is not a region token (they start with {REGION_TOKEN_PREFIX!r})")
    try:
        packed = base64.b64decode(token[len(REGION_TOKEN_PREFIX) :], validate=True)
    except binascii.Error:
        raise InvalidRegion(f"{name} is not valid base64") from None
    if len(packed) != (vertices + 7) // 8:
        raise InvalidRegion(f"{name} holds {8 * len(packed)} bits, not this template's {vertices} vertices")
    region = np.unpackbits(np.frombuffer(packed, np.uint8), count=vertices).astype(bool)
    if not region.any():
        raise InvalidRegion(f"{name} is an empty region")
    return region


# The graph's metadata key: a union step is told the overlap and boundary share its operands'
# regions measure (where the client told none) when the measured overlap is below this value,
# chosen at export as the one whose unions erred least on validation pairs (0: never told).
TELL_BELOW_KEY = "tell_overlap_below"


@dataclass(frozen=True)
class Placement:
    """Where each vertex of a part lies on the template."""

    position: np.ndarray  # (n, 3) rest-pose template coordinates, metres
    confidence: np.ndarray  # (n,) probability of the template patch it was placed in
    vertex: np.ndarray  # (n,) the template vertex nearest to its position


@dataclass(frozen=True)
class PlacedPart:
    """A part placed on the template, and the template region it covers."""

    placement: Placement
    region: np.ndarray  # (V,) bool


class TemplateRegions:
    """The template's edge graph and areas: regions from placed vertices, and their measures."""

    def __init__(self, template: Template, vertex_area: np.ndarray) -> None:
        v, f = template.vertices, template.faces
        self.graph = edge_graph(v, f)
        self.vertex_area = vertex_area
        self.tree = cKDTree(v)
        self.boundaries = RegionBoundaries(v, f)

    def nearest(self, positions: np.ndarray) -> np.ndarray:
        """(n,) the template vertex nearest to each rest-pose position."""
        return self.tree.query(positions)[1]

    def reached(self, positions: np.ndarray) -> np.ndarray:
        """(V,) bool: the template region a part's places (n, 3) reach: the template vertices
        within :data:`REACH_M` of a place, closed by :data:`CLOSING_M` along the edges."""
        distance, _ = cKDTree(positions).query(self.tree.data, distance_upper_bound=REACH_M)
        grown = self._within(np.flatnonzero(np.isfinite(distance)))
        outside = np.flatnonzero(~grown)
        return grown & ~self._within(outside) if len(outside) else grown

    def _within(self, sources: np.ndarray) -> np.ndarray:
        distance = dijkstra(self.graph, indices=sources, min_only=True, limit=CLOSING_M)
        return np.isfinite(distance)

    def overlap_share(self, a: np.ndarray, b: np.ndarray) -> float:
        """The share of the smaller region's area inside the other (0 … 1), as the union
        operator's ``overlap`` means it."""
        area = self.vertex_area
        smaller = min(float(area[a].sum()), float(area[b].sum()))
        return float(area[a & b].sum()) / smaller if smaller > 0 else 0.0

    def fold(self, regions: list[np.ndarray]) -> tuple[list[float], list[float]]:
        """Each step's overlap share and boundary share along the left fold ((A ∪ B) ∪ C) ∪ …
        of parts' regions (V,) on the template, as the union operator reads them: the union so
        far against the next part. ``len(regions) − 1`` of each."""
        overlaps, boundaries = [], []
        so_far = regions[0]
        for region in regions[1:]:
            overlaps.append(min(self.overlap_share(so_far, region), 1.0))  # shares of sums: rounding past 1
            boundaries.append(min(float(self.boundaries.shares(so_far[None], region[None])[0]), 1.0))
            so_far = so_far | region
        return overlaps, boundaries


class CorrespondenceModel:
    """The ONNX correspondence graph and the template it places parts on."""

    def __init__(self, path: Path, regions: TemplateRegions, threads: int = 1) -> None:
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        names = tuple(node.name for node in self.session.get_inputs())
        if names != CORRESPONDENCE_INPUTS:
            raise ValueError(f"the correspondence graph reads {names}, not {CORRESPONDENCE_INPUTS}")
        self.regions = regions
        metadata = self.session.get_modelmeta().custom_metadata_map
        self.tell_below = float(metadata.get(TELL_BELOW_KEY, 0.0))

    def place(self, inputs: PartInputs) -> Placement:
        """Each vertex of a part (its inputs from app.geometry.descriptors) on the template."""
        position, confidence = self.session.run(None, inputs.feeds())
        if not (np.isfinite(position).all() and np.isfinite(confidence).all()):
            raise ValueError("the correspondence graph returned non-finite places")
        position = position.astype(np.float64)
        return Placement(position, confidence.astype(np.float64), self.regions.nearest(position))

    def region(self, placement: Placement) -> np.ndarray:
        """(V,) bool: the template region the placed part covers."""
        return self.regions.reached(placement.position)

    def placed(self, inputs: PartInputs) -> PlacedPart:
        placement = self.place(inputs)
        return PlacedPart(placement, self.region(placement))
