"""The paper's tables on our data: union spectra (Table 1) and localization (Tables 2, 3).

Every row is a (split, group, variant) cell of the test sets; each row carries the operator's
errors next to the baselines' (same rows, same run), the calibration of the operator's stated
90 % intervals, and the localizers' symmetric IoU and accuracy. Chains of three parts, point-cloud
parts and the pose noise floor (one region of one identity across poses) complete the picture.
"""

from dataclasses import dataclass

import numpy as np

from app.contract import (
    INTERVAL_Z,
    MASK_THRESHOLD,
)
from app.inference import chained_sigma, localized_region
from training.common.data import PairTable, SpectralData
from training.common.spectral_errors import spectral_errors
from training.data.overlaps import CAMERA
from training.data.pairs import FULL_COVERAGE, PARTIAL_UNION, STRATA, overlap_strata
from training.data.spectra import CLOUD, MESH, REMESHED, task_spectrum
from training.localizer.masks import (
    PARTS_UNITED,
    SERVED_LOCALIZER,
    UNION_WITH_PARTS,
    symmetric_scores,
    united_by_mirror_rule,
)
from training.union.baselines import UnionLookup, disjoint_union, elementwise_min, larger_part
from training.union.predictors import RegionPredictor, ToldPredictor, UnionPredictor

GROUPS = ("known_man", "unknown_man", "unknown_woman", "known_woman", "child")
SPLITS = ("test_a", "test_b")
NOISE_FLOOR_REGIONS = 100

# The paper's figures (its Tables 1-3), keyed like our rows: (mse, mae) and (IoU %, accuracy %).
PAPER_UNION = {
    "test_a/known_man/mesh": (11.14, 2.09),
    "test_a/unknown_man/mesh": (13.25, 2.59),
    "test_a/unknown_woman/mesh": (36.92, 3.93),
    "test_a/known_man/remeshed": (29.61, 3.31),
    "test_a/unknown_man/remeshed": (32.67, 3.60),
    "test_a/unknown_woman/remeshed": (62.33, 5.23),
    "test_b/known_man/mesh": (15.41, 2.59),
    "test_b/unknown_man/mesh": (24.05, 3.60),
    "test_b/unknown_woman/mesh": (64.47, 4.99),
    "test_b/known_man/remeshed": (51.20, 4.54),
    "test_b/unknown_man/remeshed": (75.91, 5.90),
    "test_b/unknown_woman/remeshed": (110.17, 6.78),
}
PAPER_IOU = {
    "one": {
        "test_a/known_man/mesh": (99.28, 99.61),
        "test_a/unknown_man/mesh": (93.78, 95.83),
        "test_a/unknown_woman/mesh": (94.19, 96.32),
        "test_a/known_man/remeshed": (98.54, 99.06),
        "test_a/unknown_man/remeshed": (91.44, 94.08),
        "test_a/unknown_woman/remeshed": (93.47, 95.56),
        "test_b/known_man/mesh": (97.96, 98.55),
        "test_b/unknown_man/mesh": (87.58, 92.52),
        "test_b/unknown_woman/mesh": (96.05, 98.46),
        "test_b/known_man/remeshed": (93.04, 97.33),
        "test_b/unknown_man/remeshed": (83.69, 91.08),
        "test_b/unknown_woman/remeshed": (95.59, 98.43),
    },
    "six": {
        "test_a/known_man/mesh": (98.24, 99.09),
        "test_a/unknown_man/mesh": (96.26, 97.64),
        "test_a/unknown_woman/mesh": (96.17, 98.04),
        "test_a/known_man/remeshed": (97.70, 98.74),
        "test_a/unknown_man/remeshed": (95.88, 97.78),
        "test_a/unknown_woman/remeshed": (96.04, 97.66),
        "test_b/known_man/mesh": (97.43, 99.14),
        "test_b/unknown_man/mesh": (93.31, 98.23),
        "test_b/unknown_woman/mesh": (95.74, 98.59),
        "test_b/known_man/remeshed": (97.61, 99.11),
        "test_b/unknown_man/remeshed": (90.85, 97.63),
        "test_b/unknown_woman/remeshed": (96.81, 98.98),
    },
}


# The told overlap as a caller measures it: the true share plus this much absolute noise (fixed seed).
TOLD_NOISE = 0.1
# The told boundary share as a caller measures it: the true one plus this much absolute noise
# (twice the mean error of one measured from registered views, benchmarks.measured_overlap).
BOUNDARY_NOISE = 0.06


def strata(data: SpectralData, rows: PairTable) -> np.ndarray:
    """The overlap stratum (a name of ``STRATA``) of every row."""
    inside = data.overlap_shares(rows.mask_a, rows.mask_b)
    same_region = rows.mask_a == rows.mask_b
    identical = same_region & (rows.shape_a == rows.shape_b) & (rows.variant == MESH)
    return overlap_strata(inside, same_region, identical)


@dataclass
class Evaluator:
    """Everything the rows share: data, predictors, the lookup of the training pairs, areas."""

    data: SpectralData
    union: UnionPredictor
    localizers: dict[str, RegionPredictor]
    told: ToldPredictor | None = None

    def __post_init__(self) -> None:
        pairs = self.data.pairs
        train = pairs.rows(np.flatnonzero(pairs.split == "train"))
        self.lookup = UnionLookup(train.a, train.b, train.union)
        self.areas = self.data.vertex_area

    def row(self, rows: PairTable, localization: bool = True) -> dict:
        mean, sigma = self.union(rows.a, rows.b)
        methods = {
            "operator": mean,
            "elementwise_min": elementwise_min(rows.a, rows.b),
            "disjoint_union": disjoint_union(rows.a, rows.b),
            "larger_part": larger_part(
                rows.a, rows.b, self.data.mask_area(rows.mask_a), self.data.mask_area(rows.mask_b)
            ),
            "lookup": self.lookup.predict(rows.a, rows.b),
        }
        out: dict = {"rows": len(rows), "union": {name: spectral_errors(p, rows.union) for name, p in methods.items()}}
        out["interval_coverage"] = float(np.mean(np.abs(mean - rows.union) <= INTERVAL_Z * sigma))
        out["above_minimum"] = float(np.mean(mean > np.minimum(rows.a, rows.b) * (1 + 1e-6)))
        if not localization:
            return out
        truth = self.data.masks(rows.mask_union)
        template = self.data.template
        probability = {name: region(mean) for name, region in self.localizers.items()}
        predicted = {name: p >= MASK_THRESHOLD for name, p in probability.items()}  # the paper's rule
        if SERVED_LOCALIZER in self.localizers:  # each part localized: united, and as /v1/localize answers
            parts = [self.localizers[SERVED_LOCALIZER](part) for part in (rows.a, rows.b)]
            predicted[PARTS_UNITED] = united_by_mirror_rule(
                *(p >= MASK_THRESHOLD for p in parts), self.areas, template.mirror
            )
            served = probability[SERVED_LOCALIZER]
            predicted[UNION_WITH_PARTS] = localized_region(served, parts, self.areas, template.mirror)
        out["localization"] = {name: self._scores(masks, truth) for name, masks in predicted.items()}
        return out

    def _scores(self, masks: np.ndarray, truth: np.ndarray) -> dict[str, float]:
        """Mean symmetric scores of (m, n) predicted masks against the true ones."""
        template = self.data.template
        scores = symmetric_scores(masks, truth, self.areas, template.mirror, template.labels)
        return {score: float(values.mean()) for score, values in vars(scores).items()}

    def stratified(self, rows: PairTable, prefix: str) -> dict:
        """:meth:`row` per overlap stratum and variant, keyed ``prefix/stratum/variant``."""
        labels = strata(self.data, rows)
        out = {}
        for stratum in STRATA:
            for variant in (MESH, REMESHED):
                selection = np.flatnonzero((labels == stratum) & (rows.variant == variant))
                if len(selection):
                    out[f"{prefix}/{stratum}/{variant}"] = self.row(rows.rows(selection))
        return out

    def told_rows(self, rows: PairTable, labels: np.ndarray, prefix: str) -> dict:
        """The operator told each pair's overlap, exactly and as measured (± ``TOLD_NOISE``), per
        label (e.g. overlap stratum) and variant, keyed ``prefix/label/variant``; beside it the
        operator not told, on the same rows."""
        if self.told is None:
            return {}
        shares = self.data.overlap_shares(rows.mask_a, rows.mask_b)
        noise = np.random.default_rng(0).normal(0.0, TOLD_NOISE, len(shares))
        answers = {
            "not_told": self.union(rows.a, rows.b),
            "told": self.told(rows.a, rows.b, shares),
            "told_noisy": self.told(rows.a, rows.b, np.clip(shares + noise, 0.0, 1.0)),
        }
        if self.told.reads_boundary:  # told the boundary share too, exactly and as measured (± BOUNDARY_NOISE)
            boundaries = self.data.boundary_shares(rows.mask_a, rows.mask_b, rows.mask_union)
            edge_noise = np.random.default_rng(1).normal(0.0, BOUNDARY_NOISE, len(shares))
            answers["told_boundary"] = self.told(rows.a, rows.b, shares, boundaries)
            noisy = np.clip(shares + noise, 0.0, 1.0), np.clip(boundaries + edge_noise, 0.0, 1.0)
            answers["told_boundary_noisy"] = self.told(rows.a, rows.b, *noisy)
        out = {}
        for label in np.unique(labels):
            for variant in (MESH, REMESHED):
                chosen = np.flatnonzero((labels == label) & (rows.variant == variant))
                if not len(chosen):
                    continue
                truth = rows.union[chosen]
                out[f"{prefix}/{label}/{variant}"] = {
                    "rows": len(chosen),
                    "union": {name: spectral_errors(mean[chosen], truth) for name, (mean, _) in answers.items()},
                    "interval_coverage": {
                        name: float(np.mean(np.abs(mean[chosen] - truth) <= INTERVAL_Z * sigma[chosen]))
                        for name, (mean, sigma) in answers.items()
                    },
                }
        return out

    def camera_kinds(self, rows: PairTable) -> dict:
        """Operator and baselines per kind of session pair (mesh parts): what a scanner sends."""
        out = {}
        for kind in CAMERA:
            selection = np.flatnonzero((rows.scenario == kind) & (rows.variant == MESH))
            if len(selection):
                chosen = rows.rows(selection)
                out[kind] = {"rows": len(chosen), "union": self.row(chosen, localization=False)["union"]}
        return out

    def session_chains(self) -> dict:
        """Test C: views 0…n−1 of a session folded left by the operator, n = 3, 4, 5, against the
        true union of the n views; and the associativity gap of the operator on views 0, 1, 2."""
        chains = self.data.chains
        out: dict = {}
        if not len(chains.shape):
            return out
        views = chains.views
        current = {"operator": views[:, 0], "lookup": views[:, 0], "disjoint_union": views[:, 0]}
        boundaries = None
        if self.told is not None:
            current["operator_told"] = views[:, 0]
            if self.told.reads_boundary:
                current["operator_told_boundary"] = views[:, 0]
                boundaries = self.data.chain_boundaries()
        sigma = np.zeros_like(views[:, 0])
        shares = self.data.chain_shares() if self.told is not None else None
        served = self.localizers.get(SERVED_LOCALIZER)
        view_probabilities = [] if served is None else [served(views[:, i]) for i in range(views.shape[1])]
        for length in range(2, views.shape[1] + 1):
            step = views[:, length - 1]
            union, step_sigma = self.union(current["operator"], step)
            sigma = chained_sigma(current["operator"], sigma, union, step_sigma)
            current["operator"] = union
            if shares is not None:  # told the share of the smaller of (views so far, next view) inside the other
                current["operator_told"] = self.told(current["operator_told"], step, shares[:, length - 2])[0]
            if boundaries is not None:  # … and the boundary share of the step
                told = shares[:, length - 2], boundaries[:, length - 2]
                current["operator_told_boundary"] = self.told(current["operator_told_boundary"], step, *told)[0]
            current["lookup"] = self.lookup.predict(current["lookup"], step)
            current["disjoint_union"] = disjoint_union(current["disjoint_union"], step)
            if length < 3:
                continue
            truth = chains.unions[:, length - 2]
            methods = {**current, "elementwise_min": views[:, :length].min(axis=1)}
            out[str(length)] = {
                "rows": len(truth),
                "union": {name: spectral_errors(p, truth) for name, p in methods.items()},
                "interval_coverage": float(np.mean(np.abs(current["operator"] - truth) <= INTERVAL_Z * sigma)),
            }
            if served is not None:  # as /v1/localize answers the session's views
                parts = view_probabilities[:length]
                region = localized_region(served(current["operator"]), parts, self.areas, self.data.template.mirror)
                truth_region = self.data.masks(chains.union_masks[:, length - 2])
                out[str(length)]["localization"] = {UNION_WITH_PARTS: self._scores(region, truth_region)}
        left = self.union(self.union(views[:, 0], views[:, 1])[0], views[:, 2])[0]
        right = self.union(views[:, 0], self.union(views[:, 1], views[:, 2])[0])[0]
        gap = np.abs(left - right) / np.maximum(np.abs(right), 1e-6)
        out["associativity"] = {"rows": len(gap), "mean_relative_gap": float(gap[:, 1:].mean())}
        return out

    def chains(self) -> dict:
        """(A ∪ B) ∪ C through the operator twice, against the true spectrum of A ∪ B ∪ C."""
        triples = self.data.triples
        a, b, c, _, abc = (s[triples.test] for s in triples.spectra)
        if not len(a):
            return {"rows": 0}
        inner, inner_sigma = self.union(a, b)
        outer, outer_sigma = self.union(inner, c)
        chained = {
            "operator": outer,
            "elementwise_min": np.minimum(np.minimum(a, b), c),
            "disjoint_union": disjoint_union(disjoint_union(a, b), c),
            "lookup": self.lookup.predict(self.lookup.predict(a, b), c),
        }
        sigma = chained_sigma(inner, inner_sigma, outer, outer_sigma)
        return {
            "rows": int(len(a)),
            "union": {name: spectral_errors(p, abc) for name, p in chained.items()},
            "interval_coverage": float(np.mean(np.abs(outer - abc) <= INTERVAL_Z * sigma)),
        }

    def noise_floor(self) -> dict:
        """One test union region of one identity, in its own pose and another: the spread poses cause."""
        pairs = self.data.pairs
        rows = np.flatnonzero((pairs.split == "test_a") & (pairs.variant == MESH) & (pairs.scenario == "partial"))
        rows = rows[:NOISE_FLOOR_REGIONS]
        shapes = np.load(self.data.root / "work" / "shapes.npy", mmap_mode="r")
        poses = self.data.shapes_per_identity
        rng = np.random.default_rng(0)
        moved, truth = [], []
        for row in rows:
            shape = int(pairs.shape_a[row])
            other = shape - shape % poses + (shape % poses + int(rng.integers(1, poses))) % poses
            mask = self.data.masks(pairs.mask_union[row : row + 1])[0]
            vertices = np.asarray(shapes[other], dtype=np.float64)
            moved.append(task_spectrum(vertices, self.data.template.faces, mask, MESH, pairs.union.shape[1]))
            truth.append(pairs.union[row])
        moved_array, truth_array = np.array(moved), np.array(truth)
        finite = np.isfinite(moved_array).all(1)
        return {"rows": int(finite.sum()), **spectral_errors(moved_array[finite], truth_array[finite])}


def evaluate(
    data: SpectralData,
    union: UnionPredictor,
    localizers: dict[str, RegionPredictor],
    told: ToldPredictor | None = None,
) -> dict:
    """metrics.json's content: every test row, overlap strata, chains, point clouds and the noise
    floor; and, for an operator that reads the overlap (``told``), Test B and Test C told it."""
    evaluator = Evaluator(data, union, localizers, told)
    pairs = data.pairs
    random_pairs = np.isin(pairs.scenario, [FULL_COVERAGE, PARTIAL_UNION])  # the paper's kinds of pair
    rows = {}
    for split in SPLITS:
        for group in GROUPS:
            for variant in (MESH, REMESHED, CLOUD):
                selection = (pairs.split == split) & (pairs.group == group) & (pairs.variant == variant)
                if (selection := selection & random_pairs).any():
                    rows[f"{split}/{group}/{variant}"] = evaluator.row(pairs.rows(np.flatnonzero(selection)))
    test_c = pairs.rows(np.flatnonzero(pairs.split == "test_c"))
    overlapping_a = pairs.rows(np.flatnonzero((pairs.split == "test_a") & ~random_pairs))
    told = evaluator.told_rows(test_c, strata(data, test_c), "test_c")
    for split in SPLITS:  # the paper's rows, told: Test A and Test B by group
        chosen = pairs.rows(np.flatnonzero((pairs.split == split) & random_pairs & (pairs.variant != CLOUD)))
        told |= evaluator.told_rows(chosen, chosen.group, split)
    return {
        "rows": rows,
        **({"overlap_told": told} if told else {}),
        "strata": {**evaluator.stratified(test_c, "test_c"), **evaluator.stratified(overlapping_a, "test_a")},
        "test_c_kinds": evaluator.camera_kinds(test_c),
        "test_c_chains": evaluator.session_chains(),
        "chains": evaluator.chains(),
        "noise_floor": evaluator.noise_floor(),
        "paper": {"union": PAPER_UNION, "localization": PAPER_IOU},
    }
