"""The learned union operator folded over operands placed on the template: each step told the
overlap read from where the operands lie, where it is worth telling, and told nested where the
spectra allow it and the places are too doubtful to measure it.

This is the union of spectra whose geometry is not at hand in one frame (the paper's setting:
spectra with region tokens, or uploads in different frames or poses). ``/v1/union`` and the
sessions resource both fold through here, and so does ``benchmarks/session_unions.py``, so the
three mean one thing by "the chain".
"""

from dataclasses import dataclass
from typing import Literal

import numpy as np

from app.inference.correspondence import PlacedPart, counted
from app.inference.cover import Cover
from app.inference.models import SpectralModels, UnionEstimate
from app.inference.nesting import Nesting

# Where a union's overlaps came from: the client, registered views' footprints, or the parts'
# places on the template.
OverlapSource = Literal["told", "footprints", "correspondence"]


@dataclass(frozen=True)
class Located:
    """An operand's place on the template: what it was placed on, the area-weighted mean
    confidence of its places (1 for a region carried in a token: nothing placed here to doubt),
    its own area (m²; a carried region's template area) and whether its place is trusted."""

    cover: Cover
    confidence: float
    area: float
    trusted: bool = True

    @classmethod
    def placed(cls, part: PlacedPart) -> "Located":
        """An upload as the correspondence model placed it."""
        return cls(part.cover, part.placement.mean_confidence, float(part.placement.area.sum()), part.trusted)

    @classmethod
    def carried(cls, cover: Cover, vertex_area: np.ndarray) -> "Located":
        """A region sent in a token beside a spectrum."""
        return cls(cover, 1.0, float(vertex_area[cover.region].sum()))

    @property
    def counted(self) -> Cover:
        """What it covers as far as coverage, regions and overlaps count it: nothing where its
        place is doubted."""
        return counted(self.cover, self.trusted)


@dataclass(frozen=True)
class TemplateFold:
    """Each union step's overlap and boundary share read on the template (the steps before the
    first operand whose place is doubted: no overlap is known with it), and what the union
    operator is told of them (None where a step is left untold)."""

    overlaps: list[float]
    boundaries: list[float] | None
    told: list[float | None] | None
    told_boundaries: list[float | None] | None
    nesting: Nesting | None


def template_fold(models: SpectralModels, located: list[Located]) -> TemplateFold:
    """The steps of a left-to-right fold of ``located`` operands, read from their regions; from
    the first operand whose place is doubted on, no step is told (its region is not known, so
    neither is any overlap measured with it in the union)."""
    regions = [operand.counted.region for operand in located]
    overlaps, boundaries = models.template_regions.fold(regions)
    boundaries = boundaries if models.reads_boundary else None
    trusted = [operand.trusted for operand in located]
    known = max(trusted.index(False) - 1, 0) if not all(trusted) else len(overlaps)  # steps before the first doubted
    overlaps, boundaries = overlaps[:known], None if boundaries is None else boundaries[:known]
    told, edges = _worth_telling(models, overlaps, boundaries)
    untold = [None] * (len(located) - 1 - known)
    told = None if told is None else told + untold
    edges = None if edges is None else edges + untold
    confidence = [operand.confidence for operand in located]
    area = [operand.area for operand in located]
    return TemplateFold(overlaps, boundaries, told, edges, _nesting(models, confidence, area))


@dataclass(frozen=True)
class FoldedUnion:
    """A union folded through the learned operator: the estimate; each step's overlap and
    boundary share as told or measured (empty where neither) and where they came from; per step,
    whether the operator was told it and whether it was told nested instead."""

    result: UnionEstimate
    overlaps: list[float]
    boundaries: list[float]
    source: OverlapSource | None
    told: list[bool]
    nested: list[bool]


def folded_union(
    models: SpectralModels,
    values: list[np.ndarray],
    located: list[Located] | None,
    overlaps: list[float] | None,
    boundaries: list[float] | None,
    source: OverlapSource | None,
) -> FoldedUnion:
    """The union of ``values`` (the operands' spectra, in order): told ``overlaps`` and
    ``boundaries`` where they came from ``source`` (the client, or measured on registered
    footprints); else, where every operand is ``located`` on the template, told what their
    places say (:func:`template_fold`); else untold. Every route that answers a union folds here,
    so one request means one thing whichever route it went to."""
    told_overlaps, told_boundaries, nesting = overlaps, boundaries, None
    if located is not None and source is None and len(located) > 1:
        fold = template_fold(models, located)
        overlaps, boundaries, source = fold.overlaps, fold.boundaries, "correspondence"
        told_overlaps, told_boundaries, nesting = fold.told, fold.told_boundaries, fold.nesting
    result = models.union(values, told_overlaps, told_boundaries, nesting)
    steps = len(values) - 1 if source is not None else 0
    nested = list(result.nested) if nesting is not None else [False] * steps
    told_steps = told_overlaps if told_overlaps is not None else [None] * steps
    told = [share is not None or step for share, step in zip(told_steps, nested, strict=True)]
    return FoldedUnion(result, overlaps or [], boundaries or [], source, told, nested)


def _worth_telling(
    models: SpectralModels, overlaps: list[float], boundaries: list[float] | None
) -> tuple[list[float | None] | None, list[float | None] | None]:
    """The measured shares the union is told: each step's where its measured overlap is below the
    graph's threshold (None, untold, elsewhere); nothing for models that read no overlap, or when
    no step qualifies."""
    below = models.correspondence.tell_below if models.correspondence is not None else 0.0
    if not models.reads_overlap or not any(share < below for share in overlaps):
        return None, None
    told = [share if share < below else None for share in overlaps]
    edges = (
        None
        if boundaries is None
        else [e if share < below else None for share, e in zip(overlaps, boundaries, strict=True)]
    )
    return told, edges


def _nesting(models: SpectralModels, confidence: list[float], area: list[float]) -> Nesting | None:
    """What the union needs to tell measured steps nested (:mod:`app.inference.nesting`); None
    where the graph never tells a step nested."""
    below = models.correspondence.nested_below if models.correspondence is not None else 0.0
    return Nesting(confidence, area, below) if below > 0 else None
