"""Pairs that overlap the way scans do: a part with itself, re-scanned, nested, and camera views.

Random region pairs overlap by a thin band (each part adds at least ``MIN_GAIN`` to the other),
so a union operator trained on them alone never learns that U(A, A) = A or that U(A, B) = B
for A ⊂ B. These rows close that gap, most at the price of no new spectrum:

- *identical*: (A, A) on one body, literally the same spectrum twice;
- *rescan*: A, and A again on the same identity in another pose (one new spectrum);
- *nested*: (A, A ∪ B) of an existing pair, whose union is A ∪ B (no new spectrum): strictly
  nested, or (A, whole body) for a full-coverage pair;
- *camera*: views of one scanning session (:mod:`training.data.camera`), paired as a handheld
  scanner pairs them, and chained along the orbit.

Camera pairs keep their true union: a real session's union is what the scanner saw, and on a
posed body a view and its mirror image have different spectra.
"""

from dataclasses import dataclass

import numpy as np

from training.data.pairs import FULL_COVERAGE, PARTIAL_UNION
from training.data.regions import MAX_AREA_FRACTION, RegionSampler
from training.data.rows import Rows, poses_for
from training.data.spectra import MESH

IDENTICAL, RESCAN, NESTED = "identical", "rescan", "nested"
DERIVED = (IDENTICAL, RESCAN, NESTED)
# A session's pairs: a view twice, a view on the body in another pose, the camera moved a
# little, a close-up with its far view, consecutive orbit views, the first view and a farther one.
CAMERA_SAME, CAMERA_POSE, CAMERA_RESCAN = "camera_same", "camera_pose", "camera_rescan"
CAMERA_CLOSE_UP, CAMERA_NEXT, CAMERA_FAR = "camera_close_up", "camera_next", "camera_far"
CAMERA = (CAMERA_SAME, CAMERA_POSE, CAMERA_RESCAN, CAMERA_CLOSE_UP, CAMERA_NEXT, CAMERA_FAR)
SESSION_VIEWS = 7  # orbit views 0…4, then the re-scan of view 0 and the close-up inside it
ORBIT = 5
TEST_C_GROUPS = ("unknown_man", "unknown_woman", "child")
CHAIN_COLUMNS = 1 + ORBIT + (ORBIT - 1)  # shape, the orbit's views, the unions of its prefixes


def derived_rows(writer: Rows, table: dict[str, np.ndarray], poses: tuple[int, int], counts: dict, rng) -> None:
    """Identical, rescan and nested pairs from the original mesh rows of training and Test A.

    ``counts`` maps a split to how many rows of each kind it gets (Test A: per group).
    """
    source = (table["variant"] == MESH) & np.isin(table["scenario"], [FULL_COVERAGE, PARTIAL_UNION])
    for split, count in counts.items():
        groups = [None] if split == "train" else list(dict.fromkeys(table["group"][table["split"] == split]))
        for group in groups:
            chosen = source & (table["split"] == split)
            if group is not None:
                chosen &= table["group"] == group
            candidates = np.flatnonzero(chosen)
            for kind in DERIVED:
                for row in rng.choice(candidates, size=min(count, len(candidates)), replace=False):
                    _derived(writer, table, int(row), kind, poses, rng)


def _derived(writer: Rows, table: dict[str, np.ndarray], row: int, kind: str, poses: tuple[int, int], rng) -> None:
    split, group = str(table["split"][row]), str(table["group"][row])
    shape, a, union = int(table["shape_a"][row]), int(table["mask_a"][row]), int(table["mask_union"][row])
    if kind == IDENTICAL:
        writer.put(split, group, kind, MESH, (shape, shape), (a, a, a))
    elif kind == RESCAN:
        writer.put(split, group, kind, MESH, (shape, _another_pose(shape, split, group, poses, rng)), (a, a, a))
    else:
        writer.put(split, group, kind, MESH, (shape, shape), (a, union, union))


@dataclass(frozen=True)
class Chains:
    """Chains of consecutive session views: training triples (the triples table's layout) and
    Test C chains (``CHAIN_COLUMNS``: shape, views 0…4, unions of views 0…1, 0…2, 0…3, 0…4)."""

    triples: np.ndarray
    test: np.ndarray


def session_rows(
    writer: Rows, sampler: RegionSampler, sessions: dict[str, np.ndarray], poses: tuple[int, int], rng
) -> Chains:
    """The pairs and chains of every admissible drawn session (see :data:`CAMERA`)."""
    n = len(sampler.template.vertices)
    triples, test = [], []
    for packed, ok, shape, split, group in zip(
        sessions["masks"], sessions["ok"], sessions["shape"], sessions["split"], sessions["group"], strict=True
    ):
        if not ok:
            continue
        views = np.unpackbits(packed, axis=-1, count=n).astype(bool)
        session = _SessionWriter(writer, sampler, views, packed, int(shape), str(split), str(group))
        other = _another_pose(int(shape), str(split), str(group), poses, rng)
        session.pair(CAMERA_SAME, 0, 0)
        session.pair(CAMERA_POSE, 0, 0, shape_b=other)
        session.pair(CAMERA_RESCAN, 0, ORBIT)
        session.pair(CAMERA_CLOSE_UP, ORBIT + 1, 0)
        for j in range(ORBIT - 1):
            session.pair(CAMERA_NEXT, j, j + 1)
        for j in range(2, ORBIT):
            session.pair(CAMERA_FAR, 0, j)
        prefixes = session.prefixes()
        if prefixes is None:
            continue
        ids = [session.ids[j] for j in range(ORBIT)]
        if split == "train":
            triples.append([0, int(shape), *ids[:3], *prefixes[:2]])
        else:
            test.append([int(shape), *ids, *prefixes])
    return Chains(np.array(triples, dtype=np.int64).reshape(-1, 7), np.array(test, dtype=np.int64).reshape(-1, 10))


def _another_pose(shape: int, split: str, group: str, poses: tuple[int, int], rng) -> int:
    """The shape of the same identity in another pose its split may use (its own if none)."""
    own = shape % poses[0]
    others = [p for p in poses_for(split, group, *poses) if p != own] or [own]
    return shape - own + int(rng.choice(others))


class _SessionWriter:
    """Rows of one session, its views' and unions' masks stored once each."""

    def __init__(self, writer: Rows, sampler: RegionSampler, views, packed, shape: int, split: str, group: str):
        self.writer, self.sampler, self.views = writer, sampler, views
        self.shape, self.split, self.group = shape, split, group
        self.ids = [writer.mask(p) for p in packed]
        self.unions: dict[bytes, int] = {}

    def union(self, mask: np.ndarray) -> int | None:
        """The mask index of a union of views, or None if it is no admissible union region."""
        if not self.sampler.is_connected(mask) or self.sampler.area_fraction(mask) > MAX_AREA_FRACTION:
            return None
        packed = np.packbits(mask)
        key = packed.tobytes()
        if key not in self.unions:
            self.unions[key] = self.writer.mask(packed)
        return self.unions[key]

    def pair(self, kind: str, a: int, b: int, shape_b: int | None = None) -> None:
        union = self.ids[a] if a == b else self.union(self.views[a] | self.views[b])
        if union is not None:
            shapes = (self.shape, self.shape if shape_b is None else shape_b)
            self.writer.put(self.split, self.group, kind, MESH, shapes, (self.ids[a], self.ids[b], union))

    def prefixes(self) -> list[int] | None:
        """Mask indices of the unions of orbit views 0…1, 0…2, …, or None if one is inadmissible."""
        out, mask = [], self.views[0]
        for j in range(1, ORBIT):
            mask = mask | self.views[j]
            index = self.union(mask)
            if index is None:
                return None
            out.append(index)
        return out
