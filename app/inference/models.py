"""The ONNX models the service runs: the union operator and the region localizer.

Loaded once at start-up (onnxruntime, CPU, no torch), after their checksums are verified.
Input and output names are the contract's (:mod:`app.contract`, which the exporter writes by);
k and the template size are read from the graphs and checked against each other and the
template, so a mismatched set of artefacts is found at start-up, not on the first request.
"""

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
from scipy.spatial import cKDTree

from app.contract import (
    BODY_FILE,
    CORRESPONDENCE_FILE,
    INTERVAL_Z,
    LOCALIZER_FILE,
    LOCALIZER_INPUTS,
    PROFILE_SHARES,
    RECONSTRUCTION_FILE,
    RECONSTRUCTION_INPUTS,
    SESSIONS_FILE,
    UNION_BOUNDARY_INPUT,
    UNION_FILE,
    UNION_OVERLAP_INPUT,
    UNKNOWN_BOUNDARY,
    UNKNOWN_OVERLAP,
    union_feeds,
)
from app.core.errors import InputError
from app.geometry.laplacian import mesh_operators
from app.inference.bodyfit import BodyBasis
from app.inference.correspondence import CorrespondenceModel, PlacedPart, TemplateRegions
from app.inference.cover import Cover
from app.inference.manifest import OPTIONAL_ARTEFACTS, verify_manifest
from app.inference.measurements import Measurer
from app.inference.nesting import NESTED_OVERLAP, Nesting, nested_step
from app.inference.spectra import InvalidSpectrum
from app.inference.template import PART_NAMES, Template, localized_region, part_coverage
from app.sessions.calibration import SessionCalibration


@dataclass(frozen=True)
class UnionEstimate:
    """A predicted union spectrum and its calibrated per-eigenvalue uncertainty (1/m²)."""

    eigenvalues: np.ndarray
    sigma: np.ndarray
    nested: tuple[bool, ...] = ()  # per step, whether it was told nested (app.inference.nesting)

    @property
    def lower(self) -> np.ndarray:
        return np.clip(self.eigenvalues - INTERVAL_Z * self.sigma, 0, None)

    @property
    def upper(self) -> np.ndarray:
        return self.eigenvalues + INTERVAL_Z * self.sigma


class InvalidOverlap(InputError):
    """Overlaps that do not fit the operands, or that the served union operator cannot read."""

    slug = "invalid-overlap"
    title = "Invalid overlap"


def graph_inputs(graph: ort.InferenceSession) -> frozenset[str]:
    """The names a graph reads (what :func:`app.contract.union_feeds` feeds a union graph by)."""
    return frozenset(node.name for node in graph.get_inputs())


def reads_overlap(union_graph: ort.InferenceSession) -> bool:
    """Whether a union graph takes the overlap input (graphs exported before it do not)."""
    return UNION_OVERLAP_INPUT in graph_inputs(union_graph)


def reads_boundary(union_graph: ort.InferenceSession) -> bool:
    """Whether a union graph takes the boundary share (graphs exported before it do not)."""
    return UNION_BOUNDARY_INPUT in graph_inputs(union_graph)


def require_overlap_reader(readable: bool) -> None:
    """An overlap, told or to be measured, is refused by models that cannot read it."""
    if not readable:
        raise InvalidOverlap("the served union operator does not read overlaps; send the request without them")


def checked_overlaps(overlaps: list[float] | None, operands: int, readable: bool) -> list[float]:
    """One overlap per union step (``operands`` − 1 of them), each a share in 0 … 1; unknown for
    every step when none are given."""
    if overlaps is None:
        return [UNKNOWN_OVERLAP] * max(operands - 1, 0)
    require_overlap_reader(readable)
    return _one_share_per_step(overlaps, operands, "overlaps", "overlap", "a share of the smaller part")


def checked_boundaries(
    boundaries: list[float] | None, overlaps: list[float] | None, operands: int, readable: bool
) -> list[float]:
    """One boundary share per union step, each in 0 … 1, told only beside the steps' overlaps
    (the boundary share refines a told overlap; alone it says nothing the models read); unknown
    for every step when none are given."""
    if boundaries is None:
        return [UNKNOWN_BOUNDARY] * max(operands - 1, 0)
    if overlaps is None:
        raise InvalidOverlap("boundary is read beside overlap: give both, one of each per union step")
    if not readable:
        raise InvalidOverlap("the served union operator does not read boundary shares; send the request without them")
    meaning = "a share of the two operands' boundary length"
    return _one_share_per_step(boundaries, operands, "boundary shares", "boundary", meaning)


def _one_share_per_step(
    values: list[float | None], operands: int, plural: str, name: str, meaning: str
) -> list[float | None]:
    """``values`` when they are one per union step (``operands`` − 1) and each in 0 … 1 (NaN is
    not); else InvalidOverlap naming the count or the value, as ``name[i]``."""
    if len(values) != operands - 1:
        steps = operands - 1
        raise InvalidOverlap(f"{len(values)} {plural} for {operands} operands: give one per union step ({steps})")
    for i, value in enumerate(values):
        if value is not None and not 0.0 <= value <= 1.0:  # NaN fails too; None: this step not told
            raise InvalidOverlap(f"{name}[{i}] is {value}: {meaning}, from 0 to 1")
    return list(values)


@dataclass(frozen=True)
class Region:
    """A localized region: template vertices inside it and the covered share of each part's area."""

    vertices: np.ndarray
    area_fraction: float
    part_coverage: dict[str, float]


def _require_finite(*outputs: np.ndarray) -> None:
    """The last guard before a response: a non-finite output would be serialized as null. Spectra
    are bounded on the way in (``MAX_EIGENVALUE``), so this is not expected to fire."""
    if not all(np.isfinite(output).all() for output in outputs):
        raise InvalidSpectrum("the models cannot represent these spectra: their output is not finite")


def chained_sigma(inner: np.ndarray, inner_sigma: np.ndarray, union: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """σ of a union whose first operand was itself a predicted union (σ ``inner_sigma``).

    The operator's own σ is for exact operands; an inner union is off by its own error, which
    moves the next union with it (where nothing is added the union *is* the inner union). So the
    inner union's relative σ is carried to the new union and added to the step's σ as an
    independent error. Without it a session's σ was the last step's alone, and the 90 % interval
    held far fewer of the truths of chains of camera views. Arrays of the same shape, 1/m².
    """
    relative = inner_sigma / np.maximum(np.abs(inner), np.maximum(inner_sigma, 1e-12))  # ≤ 1, finite at λ = 0
    return np.sqrt(sigma**2 + (relative * union) ** 2)


def _session(path: Path, threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


class SpectralModels:
    """Union operator, localizer and template from one models directory, and the shape decoder
    and the correspondence model when the directory has them (its manifest records them)."""

    def __init__(self, directory: Path, threads: int = 1) -> None:
        checked = verify_manifest(directory)
        self.directory = directory
        self.template = Template.load(directory)
        self.union_session = _session(directory / UNION_FILE, threads)
        self.localizer_session = _session(directory / LOCALIZER_FILE, threads)
        self.k = int(self.union_session.get_inputs()[0].shape[1])
        self.union_inputs = graph_inputs(self.union_session)
        self.reads_overlap = UNION_OVERLAP_INPUT in self.union_inputs  # older graphs answer unions without it
        self.reads_boundary = UNION_BOUNDARY_INPUT in self.union_inputs
        vertex_count = self.localizer_session.get_outputs()[0].shape[1]
        if vertex_count != len(self.template.vertices):
            raise ValueError(f"localizer predicts {vertex_count} vertices, template has {len(self.template.vertices)}")
        if self.localizer_session.get_inputs()[0].shape[1] != self.k:
            raise ValueError("union operator and localizer disagree on k")
        # The lumped mass of the spectrum code: the same area weights the models were scored with.
        operators = mesh_operators(self.template.vertices, self.template.faces)
        self.vertex_area = operators.mass.diagonal()
        self.decoder_session = None
        if RECONSTRUCTION_FILE in checked:
            self.decoder_session = _session(directory / RECONSTRUCTION_FILE, threads)
            decoded = self.decoder_session.get_outputs()[0].shape
            if self.decoder_session.get_inputs()[0].shape[1] != self.k or decoded[1] != vertex_count:
                raise ValueError("the shape decoder does not read this k or write this template")
        self.template_regions = TemplateRegions(self.template, operators)
        self.correspondence = None
        if CORRESPONDENCE_FILE in checked:
            self.correspondence = CorrespondenceModel(directory / CORRESPONDENCE_FILE, self.template_regions, threads)
        self.sessions = SessionCalibration.load(directory / SESSIONS_FILE, self.k) if SESSIONS_FILE in checked else None
        self.body = BodyBasis.load(directory / BODY_FILE) if BODY_FILE in checked else None
        self.measurer = Measurer.of(self.template) if self.body is not None else None
        optional = [name for name in OPTIONAL_ARTEFACTS if name in checked]
        served = [UNION_FILE, LOCALIZER_FILE, *optional]
        digest = hashlib.sha256(b"".join((directory / name).read_bytes() for name in served))
        self.version = digest.hexdigest()[:12]  # content hash: two replicas agree iff they serve the same models

    def union(
        self,
        spectra: list[np.ndarray],
        overlaps: list[float] | None = None,
        boundaries: list[float] | None = None,
        nesting: Nesting | None = None,
    ) -> UnionEstimate:
        """Union of the spectra, folded left to right: ((A ∪ B) ∪ C) ∪ …, as trained; one is
        returned as is. σ carries each inner union's uncertainty on (:func:`chained_sigma`).
        ``overlaps``, one per step where the caller knows them: the share of the smaller operand
        inside the other (the union so far and the next operand); see :func:`checked_overlaps`.
        ``boundaries`` beside them: each step's boundary share (:func:`checked_boundaries`).
        ``nesting``: where the overlaps were measured from places, each step whose spectra allow
        nesting and whose inner candidate is placed uncertainly is told nested instead
        (:func:`app.inference.nesting.nested_step`)."""
        steps = checked_overlaps(overlaps, len(spectra), self.reads_overlap)
        edges = checked_boundaries(boundaries, overlaps, len(spectra), self.reads_boundary)
        current, sigma = spectra[0].astype(np.float64), np.zeros(self.k)
        nested = []
        for step, (other, overlap, edge) in enumerate(zip(spectra[1:], steps, edges, strict=True)):
            nested.append(nesting is not None and self.reads_overlap and nested_step(nesting, step, current, other))
            overlap = NESTED_OVERLAP if nested[-1] else overlap
            told = np.array([UNKNOWN_OVERLAP if overlap is None else overlap]) if self.reads_overlap else None
            boundary = np.array([UNKNOWN_BOUNDARY if edge is None else edge]) if self.reads_boundary else None
            feeds = union_feeds(self.union_inputs, current[None], other[None], told, boundary)
            union, step_sigma = self.union_session.run(None, feeds)
            sigma = chained_sigma(current, sigma, union[0].astype(np.float64), step_sigma[0].astype(np.float64))
            current = union[0].astype(np.float64)
        _require_finite(current, sigma)
        return UnionEstimate(current, sigma, tuple(nested))

    def union_profile(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(len(PROFILE_SHARES), k) the union of two spectra told each share of
        :data:`PROFILE_SHARES`, in one batch: what ``/v1/retrieve`` ranks the stored shapes by
        when the share is not known, each shape at the share that explains it best. Raises
        InvalidOverlap for models that do not read the overlap."""
        require_overlap_reader(self.reads_overlap)
        count = len(PROFILE_SHARES)
        batch = np.repeat(a[None], count, axis=0), np.repeat(b[None], count, axis=0)
        union, _ = self.union_session.run(None, union_feeds(self.union_inputs, *batch, PROFILE_SHARES))
        _require_finite(union)
        return union.astype(np.float64)

    def localize(self, spectrum: np.ndarray, parts: Sequence[np.ndarray] = ()) -> Region:
        """The template region whose spectrum this is (up to left/right: spectra cannot tell), as
        large as the localizer expects it; for a union, given the spectra of its ``parts``, grown
        to hold each part's own region (:func:`localized_region`)."""
        spectra = np.stack([spectrum, *parts]).astype(np.float32)
        (probability,) = self.localizer_session.run(None, {LOCALIZER_INPUTS[0]: spectra})
        _require_finite(probability)
        parts_probability = list(probability[1:, None])  # one (1, n) row per part
        inside = localized_region(probability[:1], parts_probability, self.vertex_area, self.template.mirror)[0]
        return self.region_of(inside)

    def placed_region(
        self, union: Cover, placed: Sequence[PlacedPart], operands: int
    ) -> tuple[Region, np.ndarray | None]:
        """The region of ``union``, the operands' covers united on the template, and, when every
        one of the ``operands`` was placed here (``placed`` holds them all), per template vertex
        in it the confidence of the nearest placed part vertex (a vertex the heat step filled
        takes its neighbour's); else None."""
        region = self.region_of(union.region, union.share)
        if len(placed) != operands:
            return region, None
        positions = np.concatenate([part.placement.position for part in placed])
        confidence = np.concatenate([part.placement.confidence for part in placed])
        _, nearest = cKDTree(positions).query(self.template.vertices[union.region])
        return region, confidence[nearest]

    def region_of(self, inside: np.ndarray, share: np.ndarray | None = None) -> Region:
        """A template mask (V,) as a region: its vertices, area share and part coverage, summed
        from each vertex's covered ``share`` where a placed part's cover gives it, else from the
        mask."""
        shares = part_coverage(inside if share is None else share, self.vertex_area, self.template.labels)
        coverage = {name: float(value) for name, value in zip(PART_NAMES, shares, strict=True)}
        area = self.vertex_area
        return Region(np.flatnonzero(inside), float(area[inside].sum() / area.sum()), coverage)

    def reconstruct(self, spectrum: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """(V, 3) the rest-pose body, in metres on the template's topology, whose complete spectrum
        this is, known to ``sigma`` (a union's σ; zero for a measured spectrum). Raises
        LookupError when these models have no decoder."""
        if self.decoder_session is None:
            raise LookupError("these models have no shape decoder")
        inputs = (spectrum[None].astype(np.float32), sigma[None].astype(np.float32))
        feeds = dict(zip(RECONSTRUCTION_INPUTS, inputs, strict=True))
        (vertices,) = self.decoder_session.run(None, feeds)
        _require_finite(vertices)
        return vertices[0].astype(np.float64)
