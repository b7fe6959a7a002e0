"""The correspondence model as served: an uploaded part's vertices placed on the template, the
region of the template they reach, and the overlap of two parts read on the template.

Twenty eigenvalues do not say where a part lies or how much two parts overlap; its geometry
does. The network (:data:`app.contract.CORRESPONDENCE_FILE`, trained by
``training.correspondence``) places every vertex on the template's rest pose, so two parts
scanned in different poses, frames or meshings are compared where they lie on one body, with
no registration. Optional: the service serves everything else without it.
"""

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from app.contract import CORRESPONDENCE_INPUTS
from app.geometry.descriptors import FEATURES, PartInputs, Places, magnified
from app.geometry.laplacian import Operators
from app.geometry.placing import Part
from app.inference.cover import Cover
from app.inference.nesting import NESTED_BELOW_KEY
from app.inference.relaxation import part_edges, relaxed_places
from app.inference.template import RegionBoundaries, Template

# A part's region is where its area, carried to the template by its places, lies dense. Each
# vertex's area lands on its place's nearest template vertex and spreads by one implicit heat
# step of HEAT_TIME_M2 along the template (about a Gaussian of σ = 5 cm); a template vertex is
# covered where that density, per unit of its own area and at the part's scale, reaches
# COVERED_DENSITY. Half the density is what a true outline receives, so the outline stays where
# the places put it instead of growing by a reach, and gaps between bunched places fill. The
# scale (the part's area over its region's: a bigger person) is found by SCALE_ITERATIONS of
# the fixed point. Chosen on 150 training parts (region IoU 0.78 by reach-and-close, 0.83 so),
# not on test parts.
HEAT_TIME_M2 = 1.25e-3
COVERED_DENSITY = 0.35
SCALE_ITERATIONS = 3
# A part's boundary vertices are placed worst (8.4 cm off within one edge of a camera view's
# boundary, 2.9 cm eight edges in: decision 019), so their area counts this much in its placed
# density (chosen on validation draws of the training people, every delivery, views and regions,
# as the weight whose worst set's region IoU was highest: decision 025).
BOUNDARY_WEIGHT = 0.2
# A template vertex's covered share is that density at the part's scale over the full density,
# capped at 1: per-body-part coverage sums it, not the region. The region counts the whole area
# between a ragged view's strips (its coverage points too high on camera views), the density
# alone leaves a compact part's interior short of full where the heat step carried its outline's
# area out. The full density grows with how ragged the part is, the share of its area on its
# boundary vertices (a ragged view's density spills into its gaps): FULL_DENSITY +
# FULL_DENSITY_PER_RAGGED × that share, chosen on the same draws as the line whose worst set
# erred least (decisions 022, 025).
FULL_DENSITY = 0.75
FULL_DENSITY_PER_RAGGED = 1.0


# The graph's metadata key: a union step is told the overlap and boundary share its operands'
# regions measure (where the client told none) when the measured overlap is below this value,
# chosen at export as the one whose unions erred least on validation pairs (0: never told).
TELL_BELOW_KEY = "tell_overlap_below"
# The graph's metadata key: a part whose area-weighted mean place confidence is below this value
# is answered with a warning that its places are uncertain, chosen at export as the lowest
# percentile of the validation pairs' parts (0: never). A part's mean confidence tracks its
# region's IoU on validation draws, and shapes that are no body part (a plane, a torus, a
# capsule) are placed with a fraction of a body part's.
UNCERTAIN_BELOW_KEY = "uncertain_below_confidence"
# A body part's places keep its area: carried to the template, it covers a region of about its
# own area over the person's scale squared (a 2.4 m adult would be at half of it), the area the
# network read it at (magnified) for a smaller person. A shape that is no body part can be
# placed confidently and still crowd its places onto a spot (a small closed ball). Below this
# share its places are doubted whatever their confidence
# (docs/decisions/040-a-part-whose-places-crowd-is-no-body-part.md).
CROWDED_BELOW = 0.5


@dataclass(frozen=True)
class Placement:
    """Where each vertex of a part lies on the template."""

    position: np.ndarray  # (n, 3) rest-pose template coordinates, metres
    confidence: np.ndarray  # (n,) probability of the template patch it was placed in
    vertex: np.ndarray  # (n,) the template vertex nearest to its position
    area: np.ndarray  # (n,) the part's own area at each vertex, m²
    boundary: np.ndarray  # (n,) bool: its boundary vertices
    magnification: float = 1.0  # how much larger the network read it (Places.magnification)

    @property
    def mean_confidence(self) -> float:
        """The confidence of the part's places, area-weighted: how far its region can be trusted."""
        return float(self.confidence @ self.area / self.area.sum())


@dataclass(frozen=True)
class PlacedPart:
    """A part placed on the template, what it covers there, and what makes its places doubtful
    (warnings; none where they can be trusted)."""

    placement: Placement
    cover: Cover
    doubts: tuple[str, ...] = ()

    @property
    def region(self) -> np.ndarray:
        """(V,) bool: the template region it covers."""
        return self.cover.region

    @property
    def trusted(self) -> bool:
        """Whether its region may count: in coverage, regions and measured overlaps."""
        return not self.doubts

    @property
    def counted(self) -> Cover:
        """What it covers as far as coverage, regions and overlaps count it (:func:`counted`)."""
        return counted(self.cover, self.trusted)


def counted(cover: Cover, trusted: bool) -> Cover:
    """``cover`` as coverage, regions and measured overlaps count it: nothing where the places it
    was read from are doubted (a made-up region must not say where the body was seen)."""
    return cover if trusted else Cover.of_region(np.zeros_like(cover.region))


class TemplateRegions:
    """The template's areas, nearest-vertex tree and heat step: regions from placed parts, and
    their measures."""

    def __init__(self, template: Template, operators: Operators) -> None:
        v, f = template.vertices, template.faces
        self.vertex_area = operators.mass.diagonal()
        self.tree = cKDTree(v)
        self.boundaries = RegionBoundaries(v, f)
        self.heat = splu((operators.mass + HEAT_TIME_M2 * operators.stiffness).tocsc())

    def nearest(self, positions: np.ndarray) -> np.ndarray:
        """(n,) the template vertex nearest to each rest-pose position."""
        return self.tree.query(positions)[1]

    def density(self, vertex: np.ndarray, area: np.ndarray) -> np.ndarray:
        """(V,) the area of a part landed on template vertices ``vertex`` (n,) with ``area`` (n,),
        spread by the heat step, per unit of template area (1 inside a part of the template's
        own scale placed exactly; the heat step keeps the total)."""
        landed = np.bincount(vertex, weights=area, minlength=len(self.vertex_area))
        return self.heat.solve(landed) if landed.any() else landed

    def cover(self, vertex: np.ndarray, area: np.ndarray, boundary: np.ndarray | None = None) -> Cover:
        """What a part covers: its region (see :data:`COVERED_DENSITY`) and each vertex's share
        (:data:`FULL_DENSITY`), its ``boundary`` vertices' area counted by
        :data:`BOUNDARY_WEIGHT`; the template vertices its places land on, fully, where no vertex
        is dense enough (a part of a few vertices)."""
        on_boundary = np.zeros(len(area), bool) if boundary is None else boundary
        weight = np.where(on_boundary, BOUNDARY_WEIGHT * area, area)
        ragged = float(area[on_boundary].sum() / area.sum())
        density = self.density(vertex, weight)
        total, scale = float(weight.sum()), 1.0
        region = density >= COVERED_DENSITY
        for _ in range(SCALE_ITERATIONS):
            if not region.any():
                break
            scale = total / float(self.vertex_area[region].sum())
            region = density >= COVERED_DENSITY * scale
        if region.any():
            full = FULL_DENSITY + FULL_DENSITY_PER_RAGGED * ragged
            return Cover(region, np.clip(density / (full * scale), 0.0, 1.0))
        landed = np.zeros(len(self.vertex_area), bool)
        landed[vertex] = True
        return Cover.of_region(landed)

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


# The network learnt adults (the training identities are men and women): a child's part, two
# thirds of an adult's size, reads as another part of a bigger body and is placed 10-40 cm off.
# Read magnified to an adult's size it is placed as well as an adult's, and the network's own
# mean confidence peaks at that magnification (anny calibration people, men, women and
# children: docs/decisions/053-a-part-is-placed-at-the-size-the-network-knows.md). The graph
# climbs a ladder of magnifications MAGNIFICATION_STEP apart from 1 toward the more confident
# side while the confidence rises, leaving 1 only for a gain above LEAVE_MARGIN (an adult's part
# is read as sent), between MAGNIFICATION_STEPS' ends: 0.76 (a tall adult) to 2.0 (a toddler).
MAGNIFICATION_STEP = 1.15
MAGNIFICATION_STEPS = (-2, 5)
LEAVE_MARGIN = 0.02


@dataclass(frozen=True)
class _Read:
    """The graph's places and confidences of a part's inputs (as read, maybe magnified)."""

    inputs: PartInputs
    position: np.ndarray
    confidence: np.ndarray

    @property
    def mean_confidence(self) -> float:
        """Area-weighted, as :attr:`Placement.mean_confidence` is."""
        mass = self.inputs.mass
        return float(self.confidence @ mass) / float(mass.sum())


class PlacingGraph:
    """The ONNX correspondence graph alone: a part's inputs → each vertex's place and confidence,
    read at the magnification that places it surest. What a solver worker runs
    (:func:`places_in_worker`), so that the graph's memory and time fall under the worker's cap
    and deadline, not the API process's."""

    def __init__(self, path: Path, threads: int = 1) -> None:
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        names = tuple(node.name for node in self.session.get_inputs())
        if names != CORRESPONDENCE_INPUTS:
            raise ValueError(f"the correspondence graph reads {names}, not {CORRESPONDENCE_INPUTS}")
        width = self.session.get_inputs()[0].shape[1]
        if width != FEATURES:  # a graph trained on other features would answer, wrongly
            raise ValueError(f"the correspondence graph reads {width} features, the engine computes {FEATURES}")
        metadata = self.session.get_modelmeta().custom_metadata_map
        self.tell_below = float(metadata.get(TELL_BELOW_KEY, 0.0))
        self.nested_below = float(metadata.get(NESTED_BELOW_KEY, 0.0))
        self.uncertain_below = float(metadata.get(UNCERTAIN_BELOW_KEY, 0.0))

    def run(self, part: Part, relaxed: bool = False) -> Places:
        """The places of the part's own vertices: the graph run on what it reads of the part (the
        part, or its collapsed copy) at the magnification that places it surest, its places
        (``relaxed``: relaxed toward that part's edge lengths as magnified,
        :mod:`app.inference.relaxation`) handed to the part's vertices."""
        started = time.perf_counter()
        step, read = self._surest(part.inputs)
        graph_ms = (time.perf_counter() - started) * 1e3
        position = read.position
        if relaxed:
            position = relaxed_places(position, read.confidence, read.inputs.points, part_edges(read.inputs))
        return part.expand(Places(position, read.confidence, graph_ms, MAGNIFICATION_STEP**step))

    def _surest(self, inputs: PartInputs) -> tuple[int, _Read]:
        """The step of the magnification the climb settles on (see :data:`MAGNIFICATION_STEP`)
        and the graph's reading of the inputs magnified so."""
        tried: dict[int, _Read] = {}

        def at(step: int) -> _Read:
            if step not in tried:
                read = inputs if step == 0 else magnified(inputs, MAGNIFICATION_STEP**step)
                tried[step] = _Read(read, *self._graph(read))
            return tried[step]

        lowest, highest = MAGNIFICATION_STEPS
        for direction in (1, -1):
            step = 0
            while lowest <= step + direction <= highest:
                margin = LEAVE_MARGIN if step == 0 else 0.0
                if at(step + direction).mean_confidence <= at(step).mean_confidence + margin:
                    break
                step += direction
            if step:
                return step, at(step)
        return 0, at(0)

    def _graph(self, inputs: PartInputs) -> tuple[np.ndarray, np.ndarray]:
        position, confidence = self.session.run(None, inputs.feeds())
        if not (np.isfinite(position).all() and np.isfinite(confidence).all()):
            raise ValueError("the correspondence graph returned non-finite places")
        return position, confidence


_WORKER_GRAPHS: dict[str, PlacingGraph] = {}


def places_in_worker(path: str, part: Part, relaxed: bool = False) -> Places:
    """The graph at ``path`` run on one part (its places on the part's own vertices, ``relaxed``
    or as the network gave them), its session made once per worker process."""
    if path not in _WORKER_GRAPHS:
        _WORKER_GRAPHS[path] = PlacingGraph(Path(path))
    return _WORKER_GRAPHS[path].run(part, relaxed)


class CorrespondenceModel:
    """The correspondence graph and the template it places parts on."""

    def __init__(self, path: Path, regions: TemplateRegions, threads: int = 1) -> None:
        self.path = path
        self.graph = PlacingGraph(path, threads)
        self.regions = regions
        self.tell_below = self.graph.tell_below
        self.nested_below = self.graph.nested_below
        self.uncertain_below = self.graph.uncertain_below

    def place(self, part: Part, places: Places | None = None) -> Placement:
        """Each vertex of a part (app.geometry.placing) on the template: by ``places`` a worker
        computed, else by the graph run here."""
        return self.placement(part, self.graph.run(part) if places is None else places)

    def placement(self, part: Part, places: Places) -> Placement:
        """A part's places on its own vertices, with each one's nearest template vertex."""
        position = places.position.astype(np.float64)
        nearest = self.regions.nearest(position)
        confidence = places.confidence.astype(np.float64)
        area = part.mass.astype(np.float64)
        return Placement(position, confidence, nearest, area, part.boundary, places.magnification)

    def doubts(self, placement: Placement, cover: Cover) -> list[str]:
        """A warning where the part's places cannot be trusted: too uncertain (see
        :data:`UNCERTAIN_BELOW_KEY`) or crowded onto a spot (:data:`CROWDED_BELOW`). Such a part's
        region is left out of coverage, regions and measured overlaps."""
        found = []
        confidence, below = placement.mean_confidence, self.uncertain_below
        if confidence < below:
            found.append(
                f"its places on the template are uncertain (mean confidence {confidence:.2f}, below {below:.2f}, "
                "where few body parts are placed): not part of a human body, or a view the model cannot place"
            )
        read_area = float(placement.area.sum()) * placement.magnification**2  # the area the network placed
        kept = float(self.regions.vertex_area[cover.region].sum()) / read_area
        if kept < CROWDED_BELOW:
            found.append(
                f"its places crowd onto a template region of {100 * kept:.0f} % of its area as placed (a body part's "
                f"keep at least {100 * CROWDED_BELOW:.0f} %): not part of a human body, or sent in other units"
            )
        if found:
            found.append("its region is left out of coverage, regions and measured overlaps")
        return found

    def cover(self, placement: Placement) -> Cover:
        """What the placed part covers on the template."""
        return self.regions.cover(placement.vertex, placement.area, placement.boundary)

    def placed(self, part: Part, places: Places | None = None) -> PlacedPart:
        """The part placed (by ``places`` a worker computed, else here) and what it covers."""
        placement = self.place(part, places)
        cover = self.cover(placement)
        return PlacedPart(placement, cover, tuple(self.doubts(placement, cover)))
