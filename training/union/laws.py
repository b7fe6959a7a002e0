"""The laws of union measured on a served operator, on parts it has never seen.

Parts are cut fresh from the template body shipped with the models (a neutral identity in the
rest pose), by the data set's own region generators and spectrum code but from a seed no build
uses, plus a depth camera's close-ups inside its far views. Needs no torch: it measures the ONNX
graph through the service's own :class:`~app.inference.models.SpectralModels`, so the figures
are the ones a client gets. The tests assert them (``tests/inference/test_union_laws.py``);
``benchmarks/bench_union_laws.py`` prints them for any models folder, for before/after tables.
"""

from dataclasses import dataclass

import numpy as np

from app.geometry import SpectrumOptions, mesh_spectrum
from app.inference import RegionBoundaries, SpectralModels
from training.common.spectral_errors import spectral_errors
from training.data.camera import body_mesh, close_up_camera, orbit_camera, view_mask
from training.data.pairs import NESTED_SHARE
from training.data.regions import RegionSampler
from training.data.spectra import region_mesh, remeshed

SEED = 20_261_201  # no data set build draws from this stream


def relative_error(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Mean relative error of one spectrum over the eigenvalues that are not a closed body's λ₁ = 0."""
    return spectral_errors(np.atleast_2d(predicted), np.atleast_2d(truth))["mre"]


@dataclass(frozen=True)
class LawParts:
    """Spectra of fresh parts: (inner, outer) with inner ⊂ outer, each outer again re-meshed,
    (close-up, far view) camera pairs, and the whole closed body; and the boundary share of each
    nested and camera pair's union (:class:`RegionBoundaries`)."""

    nested: list[tuple[np.ndarray, np.ndarray]]
    remeshed_outer: list[np.ndarray]
    views: list[tuple[np.ndarray, np.ndarray]]
    body: np.ndarray
    nested_boundary: list[float]
    views_boundary: list[float]


def law_parts(sampler: RegionSampler, count: int = 12, seed: int = SEED) -> LawParts:
    """``count`` nested region pairs and ``count // 2`` camera pairs on the sampler's template."""
    template = sampler.template

    def spectrum(mask: np.ndarray, remesh: bool = False) -> np.ndarray:
        mesh = region_mesh(template.vertices, template.faces, mask)
        return np.array(mesh_spectrum(remeshed(mesh) if remesh else mesh, SpectrumOptions(k=20)).eigenvalues)

    boundaries = RegionBoundaries(template.vertices, template.faces)

    def boundary_share(a: np.ndarray, b: np.ndarray) -> float:
        return float(boundaries.shares(a[None], b[None])[0])

    rng = np.random.default_rng(seed)
    nested, outers, nested_boundary, views_boundary = [], [], [], []
    while len(nested) < count:
        outer = sampler.sample(rng).mask
        centre = int(rng.choice(np.flatnonzero(outer)))
        radius = rng.uniform(0.2, 0.5)
        inner = sampler.clean(outer & (sampler.distances_from(centre, limit=radius) <= radius))
        if inner is not None and sampler.area_fraction(inner) < sampler.area_fraction(outer) - 0.05:
            nested.append((spectrum(inner), spectrum(outer)))
            outers.append(spectrum(outer, remesh=True))
            nested_boundary.append(boundary_share(inner, outer))
    mesh = body_mesh(template.vertices, template.faces)
    views = []
    while len(views) < count // 2:
        far = orbit_camera(mesh, rng.uniform(0, 2 * np.pi), rng.uniform(1.2, 2.5), rng.uniform(0.3, 1.0), 0.55)
        a = view_mask(sampler, mesh, close_up_camera(mesh, far, rng.uniform(0.35, 0.6)))
        b = view_mask(sampler, mesh, far)
        if a is not None and b is not None and sampler.area_fraction(a & b) >= NESTED_SHARE * sampler.area_fraction(a):
            views.append((spectrum(a), spectrum(b)))
            views_boundary.append(boundary_share(a, b))
    body = spectrum(np.ones(len(template.vertices), bool))
    return LawParts(nested, outers, views, body, nested_boundary, views_boundary)


def measure_laws(models: SpectralModels, parts: LawParts, seed: int = SEED) -> dict[str, list[float]]:
    """Per-case relative errors of each law, and each case's largest excess over min(a, b); for an
    operator that reads the overlap, the same laws again told it (``…_told``: the share of the
    smaller part inside the other is 1 for nested parts, one region twice and a part with the
    whole body; random shares for the bound); for one that reads the boundary share too, again
    told both (``…_boundary``: the pair's own from the template, ½ for one region twice, 0 with
    the closed body; random ones for the bound)."""

    def union(a: np.ndarray, b: np.ndarray, overlap: float | None = None, boundary: float | None = None) -> np.ndarray:
        told = None if overlap is None else [overlap]
        return models.union([a, b], told, None if boundary is None else [boundary]).eigenvalues

    pairs = [*parts.nested, *parts.views]
    singles = [s for pair in parts.nested for s in pair]
    rng = np.random.default_rng(seed + 1)
    arbitrary = [np.sort(rng.uniform(0.1, 500, len(parts.body))) for _ in range(20)]
    pool = singles + arbitrary
    draws = []
    for _ in range(60):
        i, j = rng.choice(len(pool), 2, replace=False)
        draws.append((pool[i], pool[j] * rng.uniform(0.2, 5), float(rng.uniform(0, 1)), float(rng.uniform(0, 1))))
    passes = [("", None, False)]
    if models.reads_overlap:
        passes.append(("_told", 1.0, False))
    if models.reads_boundary:
        passes.append(("_boundary", 1.0, True))
    pair_boundary = [*parts.nested_boundary, *parts.views_boundary]
    laws = {}
    for suffix, told, with_boundary in passes:

        def edge(value: float) -> float | None:
            return value if with_boundary else None  # noqa: B023 (called within this pass)

        laws |= {
            f"idempotence{suffix}": [relative_error(union(s, s, told, edge(0.5)), s) for s in singles],
            f"same_region{suffix}": [
                relative_error(union(o, r, told, edge(0.5)), o)
                for (_, o), r in zip(parts.nested, parts.remeshed_outer, strict=True)
            ],
            f"absorption{suffix}": [
                relative_error(union(a, b, told, edge(share)), b)
                for (a, b), share in zip(pairs, pair_boundary, strict=True)
            ],
            f"whole_body{suffix}": [
                relative_error(union(a, parts.body, told, edge(0.0))[1:], parts.body[1:]) for a, _ in parts.nested
            ],
            f"whole_body_lambda1{suffix}": [
                float(union(a, parts.body, told, edge(0.0))[0] / parts.body[1]) for a, _ in parts.nested
            ],
            f"excess_over_minimum{suffix}": [
                float(
                    np.max(
                        union(a, b, None if told is None else share, edge(boundary))
                        / np.maximum(np.minimum(a, b), 1e-12)
                        - 1
                    )
                )
                for a, b, share, boundary in draws
            ],
        }
    return laws
