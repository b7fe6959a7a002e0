"""The built data set as arrays the models train and are evaluated on.

``dataset.npz`` stores every spectrum once and refers to it by index; this module resolves
those indices into (part A, part B, union) spectra per row, carves a validation slice out of
the training rows (by a fixed seed) and unpacks masks on demand.
"""

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from app.geometry import mesh_operators
from app.inference import RegionBoundaries, boundary_share
from training.data.spectra import MESH
from training.data.template import Template

VALIDATION_FRACTION = 0.05


@dataclass(frozen=True)
class PairTable:
    """Rows of pairs: spectra (n, k) of both parts and of the union, with their labels."""

    a: np.ndarray
    b: np.ndarray
    union: np.ndarray
    split: np.ndarray  # train, validation, test_a, test_b
    group: np.ndarray
    scenario: np.ndarray
    variant: np.ndarray
    shape_a: np.ndarray
    shape_b: np.ndarray
    mask_a: np.ndarray
    mask_b: np.ndarray
    mask_union: np.ndarray

    def rows(self, selection: np.ndarray) -> "PairTable":
        return PairTable(**{name: getattr(self, name)[selection] for name in self.__dataclass_fields__})

    def __len__(self) -> int:
        return len(self.a)


@dataclass(frozen=True)
class TripleTable:
    """Chains (A ∪ B) ∪ C: spectra (t, k) of A, B, C, A ∪ B, A ∪ B ∪ C; ``test`` flags held-out
    ones; ``shape`` the posed body all three parts are cut from."""

    spectra: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    test: np.ndarray
    union_mask: np.ndarray
    shape: np.ndarray


@dataclass(frozen=True)
class ChainTable:
    """Test C chains of consecutive session views: spectra (c, views, k) of the views and
    (c, views − 1, k) of the unions of their prefixes (views 0…1, 0…2, …), the shapes, and the
    template masks of the views (c, views) and of the prefix unions (c, views − 1)."""

    views: np.ndarray
    unions: np.ndarray
    shape: np.ndarray
    view_masks: np.ndarray
    union_masks: np.ndarray


class SpectralData:
    """One built data set directory, loaded once."""

    def __init__(self, root: Path, seed: int = 0) -> None:
        self.root = root
        arrays = np.load(root / "dataset.npz")
        self.spectra = arrays["spectra"].astype(np.float32)
        self.masks_packed = arrays["masks"]
        self.template = Template.load(root / "template")
        self.shapes_per_identity = int(json.loads((root / "manifest.json").read_text())["preset"]["poses"])
        split = arrays["split"].astype(object)
        train = np.flatnonzero(split == "train")
        held = np.random.default_rng([seed, 7]).choice(train, int(len(train) * VALIDATION_FRACTION), replace=False)
        split[held] = "validation"
        spectra = self.spectra
        pairs = PairTable(
            a=spectra[arrays["spec_a"]],
            b=spectra[arrays["spec_b"]],
            union=spectra[arrays["spec_union"]],
            split=split.astype(str),
            group=arrays["group"],
            scenario=arrays["scenario"],
            variant=arrays["variant"],
            shape_a=arrays["shape_a"],
            shape_b=arrays["shape_b"],
            mask_a=arrays["mask_a"],
            mask_b=arrays["mask_b"],
            mask_union=arrays["mask_union"],
        )
        solved = np.isfinite(pairs.a).all(1) & np.isfinite(pairs.b).all(1) & np.isfinite(pairs.union).all(1)
        self.pairs = pairs.rows(np.flatnonzero(solved))
        triple_spectra = arrays["triple_spectra"]
        chains = tuple(spectra[triple_spectra[:, i]] for i in range(5))
        finite = np.all([np.isfinite(s).all(1) for s in chains], axis=0)
        self.triples = TripleTable(
            spectra=tuple(s[finite] for s in chains),  # type: ignore[arg-type]
            test=arrays["triples"][finite, 0].astype(bool),
            union_mask=arrays["triples"][finite, 6],
            shape=arrays["triples"][finite, 1],
        )
        chain_spectra = spectra[arrays["chain_spectra"]]  # (c, 9, k): 5 views, then 4 prefix unions
        whole = np.isfinite(chain_spectra).all(axis=(1, 2))
        views = (chain_spectra.shape[1] + 1) // 2
        columns = arrays["chains"][whole]
        self.chains = ChainTable(
            chain_spectra[whole, :views],
            chain_spectra[whole, views:],
            columns[:, 0],
            columns[:, 1 : 1 + views],
            columns[:, 1 + views :],
        )

    def complete_spectra(self) -> tuple[np.ndarray, np.ndarray]:
        """(shape indices, float64 spectra) of the complete posed bodies the build solved (the whole
        template as mask, the mesh variant): ShapeDNA's stored shapes and the decoder's true spectra."""
        arrays = np.load(self.root / "dataset.npz")
        complete = (arrays["spectrum_mask"] == 0) & (arrays["spectrum_variant"] == MESH)
        return arrays["spectrum_shape"][complete], arrays["spectra"][complete]

    def identity_of(self, shape: np.ndarray) -> np.ndarray:
        return shape // self.shapes_per_identity

    @cached_property
    def vertex_area(self) -> np.ndarray:
        """Lumped (intrinsic-Delaunay) vertex areas of the template: the weight of every size measure."""
        return mesh_operators(self.template.vertices, self.template.faces).mass.diagonal()

    def mask_area(self, indices: np.ndarray) -> np.ndarray:
        """Template area (m²) of each of the masks ``indices``."""
        return self.masks(indices) @ self.vertex_area

    def coverage(self, indices: np.ndarray) -> np.ndarray:
        """Share (0…1) of the template body's area each of the masks ``indices`` covers."""
        return self.mask_area(indices) / self.vertex_area.sum()

    def overlap_shares(self, mask_a: np.ndarray, mask_b: np.ndarray, chunk: int = 2048) -> np.ndarray:
        """(len(mask_a),) the share of the smaller part's template area inside the other part, for
        pairs of mask indices: the overlap strata's measure, and what a caller may tell the union
        operator (UnionConfig.overlap_hint)."""
        weights = self.vertex_area
        shares = []
        for start in range(0, len(mask_a), chunk):
            window = slice(start, start + chunk)
            a, b = self.masks(mask_a[window]), self.masks(mask_b[window])
            smaller = np.minimum(a @ weights, b @ weights)
            shares.append((a & b) @ weights / np.maximum(smaller, 1e-12))
        return np.concatenate(shares) if shares else np.zeros(0)

    def chain_shares(self) -> np.ndarray:
        """(chains, views − 1) each step's true overlap along the Test C chains, as the left fold
        ((A ∪ B) ∪ C) ∪ … is told it: the union of the views so far against the next view."""
        so_far, following, _ = self._chain_steps()
        steps = [self.overlap_shares(so_far[:, i], following[:, i]) for i in range(so_far.shape[1])]
        return np.stack(steps, axis=1) if steps else np.zeros((len(self.chains.shape), 0))

    def _chain_steps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(chains, views − 1) mask indices of each step of the Test C chains' left fold: the views
        so far (the first view, then the prefix unions), the next view, and their union."""
        chains = self.chains
        so_far = np.column_stack([chains.view_masks[:, :1], chains.union_masks[:, :-1]])
        return so_far, chains.view_masks[:, 1:], chains.union_masks

    def boundary_shares(self, mask_a: np.ndarray, mask_b: np.ndarray, mask_union: np.ndarray) -> np.ndarray:
        """(len(mask_a),) how much of the two parts' boundary length is left on their union's
        boundary, L(∂(A ∪ B)) / (L(∂A) + L(∂B)), for triples of mask indices: 0 where the union is
        closed, 1 where neither part covers any of the other's boundary. With the overlap share it
        tells the union's area and boundary length, Weyl's two terms of a Dirichlet spectrum
        (measured from registered views too: app.geometry.overlap.measured_fold)."""
        lengths = self.boundary_lengths(np.concatenate([mask_a, mask_b, mask_union]))
        return boundary_share(*np.split(lengths, 3))

    def chain_boundaries(self) -> np.ndarray:
        """(chains, views − 1) each step's true boundary share along the Test C chains, as the left
        fold is told it (:meth:`chain_shares`)."""
        so_far, following, union = self._chain_steps()
        steps = [self.boundary_shares(so_far[:, i], following[:, i], union[:, i]) for i in range(so_far.shape[1])]
        return np.stack(steps, axis=1) if steps else np.zeros((len(self.chains.shape), 0))

    def boundary_lengths(self, indices: np.ndarray, chunk: int = 256) -> np.ndarray:
        """(len(indices),) the boundary length (m) of each of the masks ``indices`` on the rest-pose
        template (:class:`RegionBoundaries`). Each distinct mask is measured once per data set."""
        indices = np.asarray(indices)
        todo = np.setdiff1d(np.unique(indices), np.fromiter(self._boundary_cache, dtype=indices.dtype))
        for start in range(0, len(todo), chunk):
            window = todo[start : start + chunk]
            lengths = self._boundaries.lengths(self.masks(window))
            self._boundary_cache.update(zip(window.tolist(), lengths.tolist(), strict=True))
        return np.array([self._boundary_cache[int(i)] for i in indices], dtype=np.float64)

    @cached_property
    def _boundary_cache(self) -> dict[int, float]:
        return {}

    @cached_property
    def _boundaries(self) -> RegionBoundaries:
        return RegionBoundaries(self.template.vertices, self.template.faces)

    def masks(self, indices: np.ndarray) -> np.ndarray:
        """(len(indices), n) boolean template masks."""
        n = len(self.template.vertices)
        return np.unpackbits(self.masks_packed[indices], axis=-1, count=n).astype(bool)
