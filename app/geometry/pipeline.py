"""From uploaded bytes to a spectrum report: the path shared by the API, the CLI and training."""

import io
import json
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from app.contract import MAX_HOLE_EDGES
from app.core.errors import InputError
from app.geometry.descriptors import Places
from app.geometry.errors import InvalidGeometry
from app.geometry.io import load_shape, unit_scale
from app.geometry.laplacian import Operators, mesh_operators, point_cloud_operators
from app.geometry.overlap import Footprint, footprint_of
from app.geometry.placing import PLACED_VERTICES, Part, cloud_part, mesh_part
from app.geometry.plausibility import area_warnings
from app.geometry.shapes import Mesh, PointCloud
from app.geometry.spectrum import DEFAULT_K, eigenpairs
from app.geometry.validate import prepare_cloud, prepare_mesh

MAX_FUNCTION_VALUES = 5_000_000  # vertices × k of an eigenfunction answer: 40 MB of float64


@dataclass(frozen=True)
class SpectrumOptions:
    """What the caller controls; defaults are the service's."""

    k: int = DEFAULT_K
    units: str = "m"
    scale: float | None = None
    closed: bool = False
    boundary_indices: list[int] | None = None
    max_vertices: int = 100_000
    max_hole_edges: int = MAX_HOLE_EDGES
    cap_holes: bool = False  # meshes: cap every boundary loop, not only pin-holes (a scan's blind spots)
    placed_vertices: int = PLACED_VERTICES  # a mesh placed on the template through a copy of about this many


@dataclass(frozen=True)
class SpectrumReport:
    """The eigenvalues and what was computed, so a client can tell what it got."""

    eigenvalues: Annotated[list[float], Field(description="The first k eigenvalues, 1/m², non-decreasing.")]
    kind: Annotated[Literal["mesh", "points"], Field(description="How the file was read: a mesh or a point cloud.")]
    boundary: Annotated[
        Literal["dirichlet", "none"],
        Field(description="dirichlet: the surface has a boundary, held at zero; none: closed (λ₁ = 0)."),
    ]
    vertices: Annotated[int, Field(description="Vertices solved on, after cleaning.")]
    free_vertices: Annotated[int, Field(description="Vertices off the Dirichlet boundary (the unknowns).")]
    area_m2: Annotated[float, Field(description="Surface area in m², from the lumped mass.")]
    faces_dropped: Annotated[int, Field(description="Repeated or degenerate faces removed before assembly.")]
    components_dropped: Annotated[
        int, Field(description="Connected components (point-cloud clusters) dropped: only the largest is kept.")
    ]
    holes_filled: Annotated[
        int,
        Field(
            description="Holes capped before the solve: pin-holes (small boundary loops), or with cap_holes every loop."
        ),
    ]
    scale_to_metres: Annotated[float, Field(description="Factor applied to the file's coordinates (units or scale).")]
    assembly_ms: Annotated[float, Field(description="Laplacian assembly time.")]
    solve_ms: Annotated[float, Field(description="Eigen-solve time.")]
    warnings: Annotated[
        list[str], Field(description="What looks wrong though it was solved, e.g. an area no human scan has (units?).")
    ] = field(default_factory=list)


def spectrum_from_bytes(data: bytes, file_type: str, options: SpectrumOptions) -> SpectrumReport:
    """Parse, validate and solve; raises a ``GeometryError`` subclass for any bad input."""
    return solve_bytes(data, file_type, options, vectors=False).report


@dataclass(frozen=True)
class Solved:
    """A solve's report, and with ``vectors`` its eigenfunctions on the vertices it solved on."""

    report: SpectrumReport
    functions: np.ndarray | None  # (vertices, k), M-orthonormal, 0 on Dirichlet boundary vertices
    sources: np.ndarray  # (vertices,): index in the uploaded vertex list, -1 for a pin-hole's centre
    footprint: Footprint | None = None  # with ``footprint``: where the shape lies, to measure overlaps by
    part: Part | None = None  # with ``descriptors``: the part as the correspondence graph places it
    places: Places | None = None  # where the correspondence graph placed it, when the solver worker ran it

    def npz(self) -> bytes:
        """The eigenfunctions as the API and the CLI hand them out: an ``.npz`` of NPY arrays
        ``eigenvalues`` (k,), ``eigenfunctions`` (vertices, k), ``vertex_indices`` (vertices,)
        and ``report`` (the JSON report, as a string), readable with ``allow_pickle=False``."""
        buffer = io.BytesIO()
        np.savez(
            buffer,
            eigenvalues=np.asarray(self.report.eigenvalues),
            eigenfunctions=self.functions,
            vertex_indices=self.sources,
            report=np.array(json.dumps(asdict(self.report))),
        )
        return buffer.getvalue()


def solve_bytes(
    data: bytes,
    file_type: str,
    options: SpectrumOptions,
    *,
    vectors: bool,
    footprint: bool = False,
    descriptors: bool = False,
) -> Solved:
    """Parse, validate and solve, with or without the eigenfunctions (whose size, vertices × k,
    is bounded by MAX_FUNCTION_VALUES: the answer is as large as that), the footprint and the
    correspondence network's inputs (:mod:`app.geometry.descriptors`)."""
    scale = unit_scale(options.units, options.scale)
    shape = load_shape(data, file_type, scale=scale, max_vertices=options.max_vertices)
    count = len(shape.vertices) if isinstance(shape, Mesh) else len(shape.points)
    if vectors and count * options.k > MAX_FUNCTION_VALUES:
        raise InvalidGeometry(
            f"eigenfunctions of {count} vertices × k = {options.k} exceed {MAX_FUNCTION_VALUES} values "
            "(40 MB): ask for fewer eigenvalues"
        )
    if isinstance(shape, Mesh):
        return _solve_mesh(shape, options, scale, vectors, footprint, descriptors)
    return _solve_cloud(shape, options, scale, vectors, footprint, descriptors)


def mesh_spectrum(mesh: Mesh, options: SpectrumOptions, scale: float = 1.0) -> SpectrumReport:
    """Spectrum of a mesh in metres: Dirichlet if it has a boundary after pin-hole filling."""
    return _solve_mesh(mesh, options, scale, vectors=False).report


def cloud_spectrum(cloud: PointCloud, options: SpectrumOptions, scale: float = 1.0) -> SpectrumReport:
    """Spectrum of a point cloud in metres: plain if declared closed, else Dirichlet on its flags."""
    return _solve_cloud(cloud, options, scale, vectors=False).report


def _solve_mesh(
    mesh: Mesh,
    options: SpectrumOptions,
    scale: float,
    vectors: bool,
    footprint: bool = False,
    descriptors: bool = False,
) -> Solved:
    prepared = prepare_mesh(mesh, k=options.k, max_hole_edges=options.max_hole_edges, cap_holes=options.cap_holes)
    started = time.perf_counter()
    operators = mesh_operators(prepared.mesh.vertices, prepared.mesh.faces)
    has_boundary = bool(prepared.boundary.any())
    solved = _solve(
        operators,
        prepared.boundary if has_boundary else None,
        options.k,
        started,
        vectors=vectors,
        sources=prepared.sources,
        kind="mesh",
        faces_dropped=prepared.faces_dropped,
        components_dropped=prepared.components_dropped,
        holes_filled=prepared.holes_filled,
        scale=scale,
        points=prepared.mesh.vertices if footprint else None,
    )
    if not descriptors:
        return solved
    part = mesh_part(prepared.mesh.vertices, prepared.mesh.faces, operators, options.placed_vertices)
    return replace(solved, part=part)


def _solve_cloud(
    cloud: PointCloud,
    options: SpectrumOptions,
    scale: float,
    vectors: bool,
    footprint: bool = False,
    descriptors: bool = False,
) -> Solved:
    if options.cap_holes:
        raise InputError("cap_holes caps a mesh's boundary loops; a point cloud has none: declare it closed instead")
    prepared = prepare_cloud(cloud, k=options.k, closed=options.closed, boundary_indices=options.boundary_indices)
    started = time.perf_counter()
    operators = point_cloud_operators(prepared.cloud.points)
    solved = _solve(
        operators,
        prepared.boundary,
        options.k,
        started,
        vectors=vectors,
        sources=prepared.sources,
        kind="points",
        faces_dropped=0,
        components_dropped=prepared.components_dropped,
        holes_filled=0,
        scale=scale,
        points=prepared.cloud.points if footprint else None,
    )
    if not descriptors:
        return solved
    return replace(solved, part=cloud_part(prepared.cloud.points, prepared.boundary, operators))


def _solve(
    operators: Operators,
    fixed: np.ndarray | None,
    k: int,
    started: float,
    *,
    vectors: bool,
    sources: np.ndarray,
    kind: Literal["mesh", "points"],
    faces_dropped: int,
    components_dropped: int,
    holes_filled: int,
    scale: float,
    points: np.ndarray | None = None,
) -> Solved:
    assembled = time.perf_counter()
    values, free_functions = eigenpairs(operators, k, fixed, vectors=vectors)
    solved = time.perf_counter()
    n = operators.mass.shape[0]
    area = float(operators.mass.diagonal().sum())
    report = SpectrumReport(
        eigenvalues=values.tolist(),
        kind=kind,
        boundary="none" if fixed is None else "dirichlet",
        vertices=n,
        free_vertices=n if fixed is None else int(np.count_nonzero(~fixed)),
        area_m2=area,
        faces_dropped=faces_dropped,
        components_dropped=components_dropped,
        holes_filled=holes_filled,
        scale_to_metres=scale,
        assembly_ms=1e3 * (assembled - started),
        solve_ms=1e3 * (solved - assembled),
        warnings=area_warnings(area, scale),
    )
    functions = None
    if free_functions is not None:
        functions = np.zeros((n, k))
        functions[slice(None) if fixed is None else ~fixed] = free_functions
    shape = None if points is None else footprint_of(points, operators.mass.diagonal(), edge=fixed)
    return Solved(report, functions, sources, shape)
