"""Complete bodies as a scanner sees them: closed but for a few small blind spots.

A body scanned standing all round is never closed: the soles stand on the floor, the top of the
head is rarely seen, and an armpit or the crotch hides from every view. A hole of 0.2 % of the
body's area lifts λ₁ from 0 to ~0.6/m² and shifts every eigenvalue whose mode does not vanish
there, so a decoder that learned closed bodies answers such a scan with a stranger: one trained on
closed bodies alone rebuilt unknown people from spectra without their soles at 110 mm instead
of 3 (decision 012). Blind spots are cut out of the template (so any body on its topology, posed or
not, can be scanned) and each scan is solved as the data build solves a part: the bodies
build's scans teach the decoder (:mod:`training.reconstruction.unions`), the benchmark's
unknown people's posed bodies test it.
"""

from concurrent.futures import ProcessPoolExecutor

import numpy as np
from threadpoolctl import threadpool_limits

from training.common.data import SpectralData
from training.data.spectra import MESH, task_spectrum
from training.data.workers import mapped

SOLE_HEIGHT = (0.005, 0.03)  # m above the lowest vertex: the soles and the floor's shadow
HEAD_RADIUS = (0.02, 0.06)  # m around the top of the head
SPOT_RADIUS = (0.02, 0.06)  # m around a random vertex: an armpit, the crotch, an occluded patch
MAX_SPOTS = 3


def above_soles(vertices: np.ndarray, height: float) -> np.ndarray:
    """(V,) the vertices more than ``height`` m above the lowest: the soles and the floor's shadow cut."""
    return vertices[:, 2] > vertices[:, 2].min() + height


def away_from(vertices: np.ndarray, centre: int, radius: float) -> np.ndarray:
    """(V,) the vertices farther than ``radius`` m from vertex ``centre``: a round blind spot cut."""
    return np.linalg.norm(vertices - vertices[centre], axis=1) > radius


def head_top(vertices: np.ndarray) -> int:
    """The template's highest vertex."""
    return int(np.argmax(vertices[:, 2]))


def blind_spot_mask(vertices: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(V,) the template vertices a scan sees: the soles cut with probability 0.6, the top of the
    head with 0.4, and 0…MAX_SPOTS random spots, at least one blind spot in all."""
    while True:
        seen = np.ones(len(vertices), dtype=bool)
        if rng.random() < 0.6:
            seen &= above_soles(vertices, rng.uniform(*SOLE_HEIGHT))
        if rng.random() < 0.4:
            seen &= away_from(vertices, head_top(vertices), rng.uniform(*HEAD_RADIUS))
        for centre in rng.choice(len(vertices), rng.integers(0, MAX_SPOTS + 1), replace=False):
            seen &= away_from(vertices, centre, rng.uniform(*SPOT_RADIUS))
        if not seen.all():
            return seen


@threadpool_limits.wrap(limits=1)  # one solve per worker process
def _solve(shapes: str, shape: int, faces: np.ndarray, mask: np.ndarray, k: int, cap_holes: bool) -> np.ndarray:
    vertices = np.asarray(mapped(shapes)[shape], dtype=np.float64)
    return task_spectrum(vertices, faces, mask, MESH, k, cap_holes=cap_holes)


def scans_of_shapes(
    data: SpectralData,
    shapes: np.ndarray,
    masks: list[np.ndarray],
    k: int,
    workers: int | None = None,
    *,
    cap_holes: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """(spectra (m, k), shape (m,)) of each posed shape of the build seen through its mask (one
    per shape), rows that could not be solved left out; with ``cap_holes`` each scan's holes
    capped first, as an upload with ``cap_holes=true`` is (the closed surface's spectrum)."""
    faces, posed = data.template.faces, str(data.root / "work" / "shapes.npy")
    with ProcessPoolExecutor(workers) as pool:
        jobs = [
            pool.submit(_solve, posed, shape, faces, mask, k, cap_holes)
            for shape, mask in zip(shapes, masks, strict=True)
        ]
        spectra = np.stack([job.result() for job in jobs])
    solved = np.isfinite(spectra).all(axis=1)
    return spectra[solved], shapes[solved]


def blind_spot_spectra(
    data: SpectralData, shapes: np.ndarray, draws: int, seed: int, k: int, workers: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(spectra (m, k), shape (m,)) of ``draws`` blind-spot scans of each of the posed ``shapes``
    (indices into the build's shapes), rows that could not be solved left out."""
    rows = np.repeat(shapes, draws)
    return scans_of_shapes(data, rows, blind_spot_masks(data.template.vertices, len(rows), seed), k, workers)


def blind_spot_masks(vertices: np.ndarray, count: int, seed: int) -> list[np.ndarray]:
    """``count`` blind-spot masks (:func:`blind_spot_mask`) drawn from ``seed``, in order."""
    rng = np.random.default_rng(seed)
    return [blind_spot_mask(vertices, rng) for _ in range(count)]
