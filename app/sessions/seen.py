"""Which of a fused union's boundary points lie deep inside what the session saw, by the body
fitted to its views.

The fused union's boundary is decided point by point from the views' geometry
(:mod:`app.sessions.fused`), and on a session that nearly closes around the body a few dozen
points held at zero where views meet, far from any true hole, lift every eigenvalue. Whether a
stretch of surface was seen is what the template knows: the body fitted to the views' points
(:mod:`app.inference.bodyfit`, a few mm off where they lie) is drawn onto them vertex by vertex,
each point claims its nearest template vertex, and the vertices claimed are the template region
the session saw. A boundary point is freed where its vertex lies :data:`DEPTH` rings or more
inside that region: a ring or two of doubt where the region's edge runs (a slit between views the
truth keeps, a vertex claimed by its neighbour's point) cannot free it, and where the session saw
too little for a body, or no body fits, nothing is freed
(``docs/decisions/043-a-boundary-point-deep-inside-the-seen-template-is-freed.md``).
"""

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import qdldl
import scipy.sparse as sp
from scipy.spatial import cKDTree

from app.contract import BODY_FILE
from app.inference.bodyfit import BodyBasis, NotEnoughSeen
from app.inference.template import Template, edge_graph
from app.sessions.body import NoBodyFits, fitted_views
from app.sessions.fused import FusedCloud, View, canonical_order

DEPTH = 5  # rings of the template between a freed point's vertex and the nearest one unseen
STIFFNESS = (30.0, 30.0, 10.0, 10.0, 3.0, 3.0, 1.0, 1.0, 0.3, 0.3)  # the drawing's rounds, stiff first
DRAW_REACH = 3.0  # of the local edge length: a point pulls its nearest vertex from this far
FILL_ROUNDS = 3  # a vertex no point claims, all of whose neighbours are claimed, is seen
CLAIM = 0.5  # of the local edge length: a point this near its nearest vertex is on it


@dataclass(frozen=True)
class SeenTemplate:
    """What the check needs: the body basis fitted to the views, the template's rest-pose
    vertices and its vertex graph."""

    basis: BodyBasis
    rest: np.ndarray
    graph: sp.csr_matrix  # (V, V) 1 where two vertices share an edge

    @classmethod
    def of(cls, basis: BodyBasis, template: Template) -> "SeenTemplate":
        edges = edge_graph(template.vertices, template.faces)
        return cls(basis, template.vertices, (edges > 0).astype(np.float64).tocsr())

    @cached_property
    def degree(self) -> np.ndarray:
        """(V,) each vertex's neighbour count, read once: every round of the check needs it."""
        return np.asarray(self.graph.sum(axis=1)).ravel()


_WORKER_TEMPLATES: dict[str, SeenTemplate] = {}


def seen_in_worker(directory: str) -> SeenTemplate:
    """The models ``directory``'s body basis and template, read once per worker process."""
    if directory not in _WORKER_TEMPLATES:
        path = Path(directory)
        _WORKER_TEMPLATES[directory] = SeenTemplate.of(BodyBasis.load(path / BODY_FILE), Template.load(path))
    return _WORKER_TEMPLATES[directory]


def deep_inside(seen: SeenTemplate, views: list[View], places: list[np.ndarray], cloud: FusedCloud) -> np.ndarray:
    """(n,) which of the fused ``cloud``'s points lie DEPTH rings or more inside the template
    region the ``views`` (one frame; ``places``: each point's place on the rest-pose template)
    saw; none where no body fits them (an :data:`app.sessions.fused.InsideRule` once ``seen`` is
    bound)."""
    order = canonical_order(views)  # the fit draws its points in this order: any order, one answer
    try:
        fitted = fitted_views(seen.basis, seen.rest, [views[i] for i in order], [places[i] for i in order], True)
    except (NotEnoughSeen, NoBodyFits):
        return np.zeros(len(cloud.points), bool)
    body = _drawn_onto(seen, fitted.posed[0], cloud.points)
    edge = _edge_length(seen, body)
    distance, vertex = cKDTree(body).query(cloud.points)
    claimed = np.zeros(len(body), bool)
    claimed[vertex] = True
    region = _eroded(seen, _filled(seen, claimed), DEPTH)
    return region[vertex] & (distance < CLAIM * edge[vertex])


def _drawn_onto(seen: SeenTemplate, body: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(V, 3) the fitted ``body`` drawn onto ``points``: each round, every vertex some point is
    nearest to is pulled toward those points' mean, the pull spread over the template by a
    membrane of the round's stiffness (stiff first, so the whole body slides before any vertex
    bends). Every round's system has the same sparsity: one LDLᵀ analysis, refactored numerically
    each round."""
    laplacian = sp.diags(seen.degree) - seen.graph
    solver = None
    for stiffness in STIFFNESS:
        distance, vertex = cKDTree(body).query(points)
        near = distance < DRAW_REACH * _edge_length(seen, body)[vertex]
        vertex, gap = vertex[near], points[near] - body[vertex[near]]
        count = np.bincount(vertex, minlength=len(body)).astype(np.float64)
        pull = np.stack([np.bincount(vertex, weights=gap[:, c], minlength=len(body)) for c in range(3)], axis=1)
        upper = sp.triu(sp.diags(count + 1e-6) + stiffness * laplacian, format="csc")
        if solver is None:
            solver = qdldl.Solver(upper, upper=True)
        else:
            solver.update(upper, upper=True)
        body = body + np.column_stack([solver.solve(pull[:, c]) for c in range(3)])
    return body


def _edge_length(seen: SeenTemplate, body: np.ndarray) -> np.ndarray:
    """(V,) the mean length of each vertex's edges on ``body``."""
    rows, cols = seen.graph.nonzero()
    lengths = np.linalg.norm(body[rows] - body[cols], axis=1)
    return np.bincount(rows, weights=lengths, minlength=len(body)) / np.maximum(seen.degree, 1)


def _filled(seen: SeenTemplate, claimed: np.ndarray) -> np.ndarray:
    """``claimed`` with the vertices all of whose neighbours it holds (FILL_ROUNDS times): a
    vertex between points no point chose."""
    for _ in range(FILL_ROUNDS):
        claimed = claimed | (seen.graph @ claimed.astype(np.float64) >= seen.degree)
    return claimed


def _eroded(seen: SeenTemplate, region: np.ndarray, rings: int) -> np.ndarray:
    """The vertices of ``region`` more than ``rings`` edges from any vertex outside it."""
    for _ in range(rings):
        region = region & (seen.graph @ region.astype(np.float64) >= seen.degree)
    return region
