"""Scoring the exported correspondence graph on held-out parts, beside the trivial answers.

Every figure is of the served path: the ONNX graph through :class:`CorrespondenceModel` and its
regions. Per test set (A: training identities in held-out poses; B: unseen identities, random
regions; C: unseen identities, camera views) and per variant (mesh, re-meshed, point cloud):

- place error on the template (cm, area-weighted over each part's vertices, then averaged over
  parts), the share of vertices within 5 and 10 cm, beside the template's area centroid for
  every vertex (what an uninformed regression shrinks to);
- left/right flips: parts whose places lie nearer the mirror image of the truth than the truth;
- region IoU (area-weighted, plain and mirror-allowed) of the reached region against the true
  one, beside the whole body (IoU = the true area share) and the spectral localizer;
- part-coverage error: mean absolute difference (points) of the 16 body parts' covered shares;
- overlap share of pairs of parts cut from the same body: mean absolute error against the
  true share, read from the two reached regions.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.inference.correspondence import CorrespondenceModel, Placement, TemplateRegions
from app.inference.models import SpectralModels
from app.inference.template import Template, part_coverage
from training.correspondence.parts import VARIANTS
from training.correspondence.train import load_parts
from training.data.spectra import task_spectrum

TEST_SETS = ("test_a", "test_b", "test_c")


@dataclass(frozen=True)
class PartScore:
    error_cm: float
    within_5: float
    within_10: float
    centroid_error_cm: float
    flipped: bool
    iou: float
    iou_mirror: float
    whole_body_iou: float
    localizer_iou: float
    localizer_iou_mirror: float
    coverage_error: float
    localizer_coverage_error: float


def iou(a: np.ndarray, b: np.ndarray, area: np.ndarray) -> float:
    union = float(area[a | b].sum())
    return float(area[a & b].sum()) / union if union > 0 else 1.0


def score_part(
    part: dict[str, np.ndarray],
    placement: Placement,
    region: np.ndarray,
    truth: np.ndarray,
    localized: np.ndarray,
    template: Template,
    vertex_area: np.ndarray,
) -> PartScore:
    """One part's figures (see the module docstring)."""
    rest = template.vertices
    weight = part["mass"] / part["mass"].sum()
    target = part["target"]
    error = np.linalg.norm(placement.position - rest[target], axis=1)
    mirrored = np.linalg.norm(placement.position - rest[template.mirror[target]], axis=1)
    centroid = (vertex_area @ rest) / vertex_area.sum()
    coverage = part_coverage(np.stack([truth, region, localized]), vertex_area, template.labels)
    mirror = template.mirror
    return PartScore(
        error_cm=100 * float(weight @ error),
        within_5=float(weight @ (error <= 0.05)),
        within_10=float(weight @ (error <= 0.10)),
        centroid_error_cm=100 * float(weight @ np.linalg.norm(centroid - rest[target], axis=1)),
        flipped=bool(weight @ mirrored < weight @ error),
        iou=iou(region, truth, vertex_area),
        iou_mirror=max(iou(region, truth, vertex_area), iou(region[mirror], truth, vertex_area)),
        whole_body_iou=float(vertex_area[truth].sum() / vertex_area.sum()),
        localizer_iou=iou(localized, truth, vertex_area),
        localizer_iou_mirror=max(iou(localized, truth, vertex_area), iou(localized[mirror], truth, vertex_area)),
        coverage_error=100 * float(np.abs(coverage[1] - coverage[0]).mean()),
        localizer_coverage_error=100 * float(np.abs(coverage[2] - coverage[0]).mean()),
    )


def evaluate_correspondence(parts_dir: Path, graph: Path, models: Path) -> dict:
    """Every test set × variant's mean figures, and the overlap error of same-body pairs."""
    served = SpectralModels(models)
    template = served.template
    regions = TemplateRegions(template, served.vertex_area)
    model = CorrespondenceModel(graph, regions)
    shapes = np.load(parts_dir / "shapes.npy", mmap_mode="r")
    n = len(template.vertices)
    table: dict[str, dict] = {}
    for name in TEST_SETS:
        parts = load_parts(parts_dir, name)
        rows: dict[str, list[PartScore]] = {variant: [] for variant in VARIANTS}
        reached, truths, bodies = [], [], []
        for part in parts:
            truth = np.unpackbits(part["mask"], count=n).astype(bool)
            placement = model.place(_inputs(part))
            region = model.region(placement)
            body = np.asarray(shapes[int(part["shape"])], dtype=np.float64)
            spectrum = task_spectrum(body, template.faces, truth, str(part["variant"]), served.k)
            localized = served.localize(spectrum).vertices if np.isfinite(spectrum).all() else np.arange(n)
            localized_mask = np.zeros(n, bool)
            localized_mask[localized] = True
            rows[str(part["variant"])].append(
                score_part(part, placement, region, truth, localized_mask, template, served.vertex_area)
            )
            reached.append(region)
            truths.append(truth)
            bodies.append(int(part["shape"]))
        table[name] = {variant: _mean(scores) for variant, scores in rows.items() if scores}
        table[name]["overlap"] = _overlap_errors(regions, reached, truths, bodies)
    return table


def _inputs(part: dict[str, np.ndarray]):
    from app.geometry.descriptors import PartInputs
    from app.geometry.tangent import GradientStencil

    stencil = GradientStencil(part["neighbours"], part["weights"])
    return PartInputs(part["features"], part["mass"], part["basis"], part["eigenvalues"], stencil)


def _mean(scores: list[PartScore]) -> dict[str, float]:
    fields = PartScore.__dataclass_fields__
    return {"parts": len(scores)} | {key: float(np.mean([getattr(s, key) for s in scores])) for key in fields}


def _overlap_errors(regions: TemplateRegions, reached: list, truths: list, bodies: list) -> dict[str, float]:
    """Mean absolute error of the overlap share measured from reached regions, over every pair
    of parts of one body (any variants): the pairs a session would unite."""
    errors = []
    for i in range(len(reached)):
        for j in range(i + 1, len(reached)):
            if bodies[i] == bodies[j]:
                measured = regions.overlap_share(reached[i], reached[j])
                errors.append(abs(measured - regions.overlap_share(truths[i], truths[j])))
    return {"pairs": len(errors), "mean_absolute_error": float(np.mean(errors)) if errors else float("nan")}
