"""Scoring the exported correspondence graph on held-out parts, beside the trivial answers.

Every figure is of the served path: each part placed from its saved geometry as the service
places an upload (:mod:`app.geometry.placing`: a mesh above the vertex budget through its
collapsed copy), the ONNX graph through :class:`CorrespondenceModel` and its regions. Per test
set (A: training identities in held-out poses; B: unseen identities, random regions; C: unseen
identities, camera views) and per variant (mesh, re-meshed, point cloud):

- place error on the template (cm, area-weighted over each part's vertices, then averaged over
  parts), the share of vertices within 5 and 10 cm, beside the template's area centroid for
  every vertex (what an uninformed regression shrinks to), and of the places relaxed toward the
  part's edge lengths (what ``/v1/correspondence?places=relaxed`` answers);
- left/right flips: parts whose places lie nearer the mirror image of the truth than the truth;
- region IoU (area-weighted, plain and mirror-allowed) of the reached region against the true
  one, beside the whole body (IoU = the true area share), the spectral localizer, and the same
  region rule fed each vertex's true place (the most the rule can reach with perfect places);
- part-coverage error: mean absolute difference (points) of the 16 body parts' covered shares,
  as served (from each template vertex's covered share; the localizer's from its region);
- warned: parts answered with the warning that their places are uncertain (their mean
  confidence below the graph's threshold, the lowest percentile of the validation pairs' parts).

Pairs of parts of one person (:mod:`training.correspondence.pairs`): the overlap measured from
the two reached regions against the true one, and the union told it or not, or told the pair
nested where its spectra allow it and its inner candidate is placed uncertainly
(:mod:`app.inference.nesting`); per kind of pair and per overlap stratum (the union
evaluation's, by the pair's true overlap).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.geometry import BOUNDARY_COLUMN, Part, cloud_part, mesh_operators, mesh_part, point_cloud_operators
from app.inference import (
    NESTED_OVERLAP,
    CorrespondenceModel,
    Cover,
    Nesting,
    Placement,
    SpectralModels,
    Template,
    inner_confidence,
)
from training.common.spectral_errors import spectral_errors
from training.correspondence.pairs import PAIR_SETS, VALIDATION_SETS, load_pairs
from training.correspondence.parts import VARIANTS
from training.correspondence.train import load_parts
from training.data.pairs import overlap_strata
from training.data.spectra import task_spectrum
from training.localizer.masks import present_part_coverage, symmetric_scores
from training.union.baselines import elementwise_min

TEST_SETS = ("test_a", "test_b", "test_c")


@dataclass(frozen=True)
class PartScore:
    error_cm: float
    within_5: float
    within_10: float
    centroid_error_cm: float
    relaxed_error_cm: float
    relaxed_within_10: float
    flipped: bool
    iou: float
    iou_mirror: float
    true_places_iou: float
    whole_body_iou: float
    localizer_iou: float
    localizer_iou_mirror: float
    coverage_error: float
    localizer_coverage_error: float
    warned: bool


def region_scores(predicted: np.ndarray, truth: np.ndarray, template: Template, area: np.ndarray) -> tuple:
    """(m, n) predicted template masks against one true mask (n,): the project's mask scores
    (:func:`training.localizer.masks.symmetric_scores`) taken as they are (plain: which side the
    part lies on counts) and mirror-allowed."""
    targets = np.repeat(truth[None], len(predicted), axis=0)
    plain = symmetric_scores(predicted, targets, area, np.arange(len(truth)), template.labels)
    return plain, symmetric_scores(predicted, targets, area, template.mirror, template.labels)


def coverage_error(share: np.ndarray, truth: np.ndarray, template: Template, area: np.ndarray) -> float:
    """The mean absolute error of the body parts' covered shares, as served (summed from each
    template vertex's covered ``share``), against the true region's."""
    served, true = (present_part_coverage(mask, area, template.labels) for mask in (share, truth))
    return float(np.abs(served - true).mean())


def score_part(
    part: dict[str, np.ndarray],
    placement: Placement,
    relaxed: np.ndarray,
    cover: Cover,
    truth: np.ndarray,
    localized: np.ndarray,
    perfect: np.ndarray,
    template: Template,
    vertex_area: np.ndarray,
    warned: bool,
) -> PartScore:
    """One part's figures (see the module docstring); ``relaxed``: its places relaxed toward its
    edge lengths; ``perfect``: the region the rule reads from the part's true places;
    ``warned``: whether its answer warns of uncertain places."""
    rest = template.vertices
    weight = part["mass"] / part["mass"].sum()
    target = part["target"]
    error = np.linalg.norm(placement.position - rest[target], axis=1)
    relaxed_error = np.linalg.norm(relaxed - rest[target], axis=1)
    mirrored = np.linalg.norm(placement.position - rest[template.mirror[target]], axis=1)
    centroid = (vertex_area @ rest) / vertex_area.sum()
    plain, mirror = region_scores(np.stack([cover.region, localized, perfect]), truth, template, vertex_area)
    return PartScore(
        error_cm=100 * float(weight @ error),
        within_5=float(weight @ (error <= 0.05)),
        within_10=float(weight @ (error <= 0.10)),
        centroid_error_cm=100 * float(weight @ np.linalg.norm(centroid - rest[target], axis=1)),
        relaxed_error_cm=100 * float(weight @ relaxed_error),
        relaxed_within_10=float(weight @ (relaxed_error <= 0.10)),
        flipped=bool(weight @ mirrored < weight @ error),
        iou=float(plain.iou[0]),
        iou_mirror=float(mirror.iou[0]),
        true_places_iou=float(plain.iou[2]),
        whole_body_iou=float(vertex_area[truth].sum() / vertex_area.sum()),
        localizer_iou=float(plain.iou[1]),
        localizer_iou_mirror=float(mirror.iou[1]),
        coverage_error=100 * coverage_error(cover.share, truth, template, vertex_area),
        localizer_coverage_error=100 * float(plain.coverage_error[1]),
        warned=warned,
    )


def evaluate_correspondence(parts_dir: Path, graph: Path, models: Path) -> dict:
    """Every test set × variant's mean figures."""
    served = SpectralModels(models)
    template = served.template
    model = CorrespondenceModel(graph, served.template_regions)
    shapes = np.load(parts_dir / "shapes.npy", mmap_mode="r")
    n = len(template.vertices)
    table: dict[str, dict] = {}
    for name in TEST_SETS:
        parts = load_parts(parts_dir, name)
        rows: dict[str, list[PartScore]] = {variant: [] for variant in VARIANTS}
        for part in parts:
            truth = np.unpackbits(part["mask"], count=n).astype(bool)
            placing = served_part(part)
            placement = model.place(placing)
            relaxed = model.graph.run(placing, relaxed=True).position
            cover = model.cover(placement)
            body = np.asarray(shapes[int(part["shape"])], dtype=np.float64)
            spectrum = task_spectrum(body, template.faces, truth, str(part["variant"]), served.k)
            localized = served.localize(spectrum).vertices if np.isfinite(spectrum).all() else np.arange(n)
            localized_mask = np.zeros(n, bool)
            localized_mask[localized] = True
            perfect = model.regions.cover(part["target"], placement.area, placement.boundary).region
            rows[str(part["variant"])].append(
                score_part(
                    part,
                    placement,
                    relaxed,
                    cover,
                    truth,
                    localized_mask,
                    perfect,
                    template,
                    served.vertex_area,
                    bool(model.doubts(placement, cover)),
                )
            )
        table[name] = {variant: _mean(scores) for variant, scores in rows.items() if scores}
    return table


# The thresholds tried for telling the union the measured overlap: told where the measured share
# is below it (0: never told; above 1: always).
TELL_THRESHOLDS = (0.0, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.01)
# The thresholds tried for telling a pair nested: where its inner candidate's mean place
# confidence is below it (0: never).
NESTED_THRESHOLDS = (0.0, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7)
# A part is warned of uncertain places below this percentile of the validation pairs' parts' mean
# place confidence: the share of body parts like those trained on that a warning wrongly doubts.
UNCERTAIN_PERCENTILE = 1.0


def evaluate_pairs(parts_dir: Path, graph: Path, models: Path) -> dict:
    """The pairs' figures: the tell and nested thresholds chosen on the validation pairs
    (training people), then every test pair set's summary with them (see :func:`pair_rows`,
    :func:`summary`); and the mean place confidence below which a part is warned
    (:data:`UNCERTAIN_PERCENTILE` of the validation pairs' parts)."""
    served = SpectralModels(models)
    model = CorrespondenceModel(graph, served.template_regions)
    validation = [row for name in VALIDATION_SETS for row in pair_rows(parts_dir, name, model, served)]
    chosen = choose_thresholds(validation)
    tests = {name: pair_rows(parts_dir, name, model, served) for name in PAIR_SETS}
    return {
        "tell_below": chosen.tell_below,
        "nested_below": chosen.nested_below,
        "uncertain_below": uncertain_threshold(validation),
        "uncertain_percentile": UNCERTAIN_PERCENTILE,
        "validation": summary(validation, chosen)["all"],
        "sets": {name: summary(rows, chosen) for name, rows in tests.items()},
        "strata": {name: summary(rows, chosen, by="stratum", overall=False) for name, rows in tests.items()},
    }


def pair_rows(parts_dir: Path, name: str, model: CorrespondenceModel, served: SpectralModels) -> list[dict]:
    """Per pair of set ``name``: its kind and overlap stratum (by its true overlap, as the union's
    evaluation divides pairs), the overlap and boundary share measured from the parts' regions
    and their errors, the union's error untold / told the measured shares / told the true ones
    beside the elementwise minimum, and the union's region IoU beside the whole body and the
    spectral localizer (the union of the localized parts, as /v1/localize answers spectra)."""
    regions, n, area = served.template_regions, len(served.template.vertices), served.vertex_area
    rows = []
    for pair in load_pairs(parts_dir, name):
        a, b, union = (np.unpackbits(pair[f"mask_{s}"], count=n).astype(bool) for s in ("a", "b", "union"))
        placed = [model.placed(served_part(pair, side)) for side in ("a_", "b_")]
        measured, measured_edge = regions.fold([p.region for p in placed])
        true, true_edge = regions.fold([a, b])
        spectra = [pair["spectrum_a"], pair["spectrum_b"]]
        truth = pair["union"][None]
        untold = served.union(spectra).eigenvalues
        told = served.union(spectra, measured, measured_edge if served.reads_boundary else None).eigenvalues
        oracle = served.union(spectra, true, true_edge if served.reads_boundary else None).eigenvalues
        nested = served.union(spectra, [NESTED_OVERLAP], measured_edge if served.reads_boundary else None)
        certainty = Nesting([p.placement.mean_confidence for p in placed], [p.placement.area.sum() for p in placed], 0)
        localized = np.zeros(n, bool)
        localized[served.localize(untold, spectra).vertices] = True
        plain, mirrored = region_scores(
            np.stack([placed[0].region | placed[1].region, localized]), union, served.template, area
        )
        same_region = np.array_equal(a, b)
        identical = same_region and np.array_equal(*spectra)
        rows.append(
            {
                "kind": str(pair["kind"]),
                "stratum": str(overlap_strata(np.array(true[0]), np.array(same_region), np.array(identical))),
                "measured_overlap": measured[0],
                "overlap_error": abs(measured[0] - true[0]),
                "boundary_error": abs(measured_edge[0] - true_edge[0]),
                "true_overlap": true[0],
                "untold": spectral_errors(untold[None], truth)["mre"],
                "told_measured": spectral_errors(told[None], truth)["mre"],
                "told_truth": spectral_errors(oracle[None], truth)["mre"],
                "told_nested": spectral_errors(nested.eigenvalues[None], truth)["mre"],
                "inner_confidence": inner_confidence(certainty, 0, *spectra),
                "confidences": certainty.confidence,
                "elementwise_min": spectral_errors(elementwise_min(*(s[None] for s in spectra)), truth)["mre"],
                "iou": float(plain.iou[0]),
                "iou_mirror": float(mirrored.iou[0]),
                "whole_body_iou": float(area[union].sum() / area.sum()),
                "localizer_iou_mirror": float(mirrored.iou[1]),
            }
        )
    return rows


def uncertain_threshold(rows: list[dict]) -> float:
    """The mean place confidence below which a part is warned: :data:`UNCERTAIN_PERCENTILE` of
    the confidences of the parts of ``rows`` (validation pairs; a session's view in several pairs
    counts in each)."""
    return float(np.percentile([c for row in rows for c in row["confidences"]], UNCERTAIN_PERCENTILE))


@dataclass(frozen=True)
class Thresholds:
    """What the served union tells a measured pair: the measured shares where the measured
    overlap is below ``tell_below``; nested where its inner candidate's confidence is below
    ``nested_below`` (which wins)."""

    tell_below: float
    nested_below: float


def told_nested(row: dict, chosen: Thresholds) -> bool:
    """Whether the served union tells the pair of ``row`` nested."""
    return row["inner_confidence"] < chosen.nested_below


def served_error(row: dict, chosen: Thresholds) -> float:
    """The union's error as served (:class:`Thresholds`)."""
    if told_nested(row, chosen):
        return row["told_nested"]
    return row["told_measured"] if row["measured_overlap"] < chosen.tell_below else row["untold"]


def choose_thresholds(rows: list[dict]) -> Thresholds:
    """The tell threshold of :data:`TELL_THRESHOLDS` with the lowest mean served error over
    ``rows`` (validation pairs), never telling them nested; then with it, the nested threshold of
    :data:`NESTED_THRESHOLDS` that errs least. The lower threshold where two tie."""

    def mean_error(chosen: Thresholds) -> float:
        return float(np.mean([served_error(row, chosen) for row in rows]))

    tell = min(TELL_THRESHOLDS, key=lambda t: mean_error(Thresholds(t, 0.0)))
    nested = min(NESTED_THRESHOLDS, key=lambda t: mean_error(Thresholds(tell, t)))
    return Thresholds(tell, nested)


def summary(rows: list[dict], chosen: Thresholds, by: str = "kind", overall: bool = True) -> dict[str, dict]:
    """Mean figures per group of rows (their ``by``: kind or stratum) and, with ``overall``,
    over all rows (``all``), with the served error and the share of pairs told nested under
    ``chosen``."""
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(row[by], []).append(row)
    if overall:
        groups["all"] = rows
    out = {}
    for group, members in sorted(groups.items()):
        numbers = [
            {k: v for k, v in row.items() if k not in ("kind", "stratum", "inner_confidence", "confidences")}
            | {"served": served_error(row, chosen), "nested": float(told_nested(row, chosen))}
            for row in members
        ]
        out[group] = {"pairs": len(members)} | _means(numbers)
    return out


def _means(rows: list[dict]) -> dict[str, float]:
    return {key: float(np.mean([row[key] for row in rows])) for key in rows[0]}


def served_part(saved: dict[str, np.ndarray], prefix: str = "") -> Part:
    """A saved part (its arrays under ``prefix``) as the service places it: from its geometry, so
    that a mesh above the service's vertex budget is placed through its copy."""
    points, faces = saved[prefix + "points"], saved[prefix + "faces"]
    if faces.size == 0:  # a point cloud
        boundary = saved[prefix + "features"][:, BOUNDARY_COLUMN] > 0
        return cloud_part(points, boundary, point_cloud_operators(points))
    return mesh_part(points, faces, mesh_operators(points, faces))


def _mean(scores: list[PartScore]) -> dict[str, float]:
    fields = PartScore.__dataclass_fields__
    return {"parts": len(scores)} | {key: float(np.mean([getattr(s, key) for s in scores])) for key in fields}
