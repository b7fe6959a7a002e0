"""The pair table: drawn masks put on bodies and assigned to splits, Test B's held-out unions
realized by new pairs, test rows in their re-meshed and point-cloud variants, and the rows that
overlap as scans do.

Each kind of row draws from its own stream (:mod:`training.data.streams`), and the kinds added
later are appended after the earlier ones, so adding a kind leaves every earlier row as it was.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from training.data.overlaps import derived_rows, session_rows
from training.data.pairs import FULL_COVERAGE, OVERLAP, PARTIAL_UNION, Pair, split_union, symmetric_iou
from training.data.presets import GROUPS, TRAINING_GROUPS, Preset
from training.data.regions import RegionSampler
from training.data.rows import COLUMNS, Rows, poses_for
from training.data.spectra import CLOUD, MESH, REMESHED
from training.data.streams import serial_stream

TEST_B_MAX_IOU = 0.8  # a Test B union overlaps every training union (or its mirror) less than this
TEST_B_TYPES = 30  # held-out union types, each realized by many different pairs
SPLIT_ATTEMPTS = 20  # tries per wanted Test B pair


@dataclass
class _Placer:
    """Puts a pair of packed masks on a drawn identity of a group, in one or two of its poses."""

    writer: Rows
    identities: list[dict]
    preset: Preset

    def add(self, split: str, group: str, scenario: str, packed: np.ndarray, rng: np.random.Generator) -> None:
        """One row of ``split``: an identity of ``group``, pose A, and pose B equal to A half the time."""
        identity = int(rng.choice([i for i, m in enumerate(self.identities) if m["group"] == group]))
        pose_pool = poses_for(split, group, self.preset.poses, self.preset.test_poses)
        pose_a = int(rng.choice(pose_pool))
        pose_b = pose_a if rng.random() < 0.5 else int(rng.choice(pose_pool))
        a, b = self.writer.mask(packed[0]), self.writer.mask(packed[1])
        union = 0 if scenario == FULL_COVERAGE else self.writer.mask(packed[2])
        first = identity * self.preset.poses
        self.writer.put(split, group, scenario, MESH, (first + pose_a, first + pose_b), (a, b, union))


def assign_rows(
    preset: Preset,
    identities: list[dict],
    pairs: dict,
    triples: dict,
    sessions: dict,
    sampler: RegionSampler,
    seed: int,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The table (columns of :class:`Rows`, plus ``triples`` and ``chains``) and the packed masks it indexes."""
    rng = serial_stream(seed, "splits")
    n = len(sampler.template.vertices)
    writer = Rows([np.packbits(np.ones(n, bool))])  # mask 0: the whole body
    placer = _Placer(writer, identities, preset)
    pair_masks, pair_scenarios = pairs["pair"]["masks"], pairs["pair"]["scenario"]
    for i in range(preset.train_pairs):
        placer.add("train", str(rng.choice(TRAINING_GROUPS)), str(pair_scenarios[i]), pair_masks[i], rng)
    for g, group in enumerate(GROUPS):
        for j in range(preset.test_pairs):
            i = preset.train_pairs + g * preset.test_pairs + j
            placer.add("test_a", group, str(pair_scenarios[i]), pair_masks[i], rng)
    seen = np.concatenate(
        [pair_masks[: preset.train_pairs][pair_scenarios[: preset.train_pairs] == PARTIAL_UNION, 2]]
        + [triples["masks"][:, column] for column in (3, 4)]
    )
    held_out = _held_out_unions(_unpack(pairs["candidate"]["masks"][:, 2], n), _unpack(seen, n), sampler)
    test_b_rng = serial_stream(seed, "test_b")
    for group in GROUPS:
        for pair in _realizations(sampler, held_out, preset.test_pairs, test_b_rng):
            placer.add("test_b", group, PARTIAL_UNION, np.packbits([pair.a, pair.b, pair.union], axis=-1), test_b_rng)
    table = _with_variants(writer.take(), preset, rng)
    table["triples"] = _triple_rows(triples, preset, identities, rng, writer.mask)
    # Appended last, from their own streams: the rows above stay as they were without them.
    retrieval_rng = serial_stream(seed, "retrieval")
    for i, packed in enumerate(pairs["retrieval"]["masks"]):
        placer.add("retrieval", GROUPS[i % len(GROUPS)], FULL_COVERAGE, packed, retrieval_rng)
    table = _appended(table, writer.take())
    overlap_rng = serial_stream(seed, "overlap")
    overlap_masks = pairs["overlap"]["masks"]
    for i in range(preset.overlap_pairs):
        placer.add("train", str(overlap_rng.choice(TRAINING_GROUPS)), OVERLAP, overlap_masks[i], overlap_rng)
    for g, group in enumerate(GROUPS):
        for packed in overlap_masks[preset.overlap_pairs + g * preset.overlap_test :][: preset.overlap_test]:
            placer.add("test_a", group, OVERLAP, packed, overlap_rng)
    poses = (preset.poses, preset.test_poses)
    counts = {"train": preset.derived_pairs, "test_a": preset.derived_test}
    derived_rows(writer, table, poses, counts, serial_stream(seed, "derived"))
    chains = session_rows(writer, sampler, sessions, poses, serial_stream(seed, "sessions"))
    table = _appended(table, _remeshed_copies(writer.take()))
    table["triples"] = np.concatenate([table["triples"], chains.triples])
    table["chains"] = chains.test
    table = _appended(table, _remeshed_training(table, preset.remeshed_train, serial_stream(seed, "remeshed_train")))
    return table, np.array(writer.masks)


def _remeshed_training(table: dict[str, np.ndarray], count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``count`` training rows of every kind, drawn uniformly, again with both parts re-meshed.

    They need no new union spectrum (the union stays the mesh's) and only two part spectra
    each; a re-meshed row of one spectrum twice stays one spectrum twice, whose union is the
    mesh's: what meshing alone moves a spectrum by, which σ must cover.
    """
    train = np.flatnonzero(table["split"] == "train")
    rows = np.sort(rng.choice(train, size=min(count, len(train)), replace=False))
    copies = {key: table[key][rows] for key in COLUMNS}
    copies["variant"] = np.full(len(rows), REMESHED)
    return copies


def _appended(table: dict[str, np.ndarray], rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``table`` with ``rows`` (same columns) after its own; the other tables of it kept."""
    if not len(rows["split"]):
        return table
    return {key: np.concatenate([value, rows[key]]) if key in rows else value for key, value in table.items()}


def _unpack(packed: np.ndarray, n: int) -> np.ndarray:
    return np.unpackbits(packed, axis=-1, count=n).astype(bool).reshape(-1, n)


def _held_out_unions(candidates: np.ndarray, seen: np.ndarray, sampler: RegionSampler) -> list[np.ndarray]:
    """Union types for Test B: candidate unions unlike every seen union and unlike each other.

    "Unlike" is a symmetric IoU below ``TEST_B_MAX_IOU``. Training draws tens of thousands of
    fresh unions, which leaves few such candidates: the paper's Test B likewise has a handful
    of union types, each met in many poses, identities and part pairs.
    """
    weights, mirror = sampler.vertex_area, sampler.template.mirror
    novelty = symmetric_iou(candidates, seen, weights, mirror)
    chosen: list[np.ndarray] = []
    for i in np.flatnonzero(novelty < TEST_B_MAX_IOU):
        if len(chosen) == TEST_B_TYPES:
            break
        if not chosen or symmetric_iou(candidates[i : i + 1], np.array(chosen), weights, mirror)[0] < TEST_B_MAX_IOU:
            chosen.append(candidates[i])
    return chosen


def _realizations(sampler: RegionSampler, unions: list[np.ndarray], count: int, rng: np.random.Generator) -> list[Pair]:
    """Up to ``count`` pairs, cycling through ``unions``; a union that resists splitting gets fewer."""
    pairs: list[Pair] = []
    for attempt in range(count * SPLIT_ATTEMPTS if unions else 0):
        if len(pairs) == count:
            break
        pair = split_union(sampler, unions[attempt % len(unions)], rng)
        if pair is not None:
            pairs.append(pair)
    return pairs


def _with_variants(table: dict[str, np.ndarray], preset: Preset, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every test row again re-meshed, and some as point clouds (parts only; unions stay meshes)."""
    test = np.flatnonzero(table["split"] != "train")
    clouds = rng.choice(test, size=min(preset.cloud_parts, len(test)), replace=False)
    return _copies(_copies(table, test, REMESHED), np.sort(clouds), CLOUD, table)


def _remeshed_copies(table: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every test row again with both parts re-meshed (the union stays the mesh's)."""
    return _copies(table, np.flatnonzero(table["split"] != "train"), REMESHED)


def _copies(
    table: dict[str, np.ndarray], rows: np.ndarray, variant: str, source: dict[str, np.ndarray] | None = None
) -> dict[str, np.ndarray]:
    """``table`` followed by ``rows`` of ``source`` (default: of ``table``) in ``variant``."""
    source = table if source is None else source
    return {
        key: np.concatenate([value, np.full(len(rows), variant) if key == "variant" else source[key][rows]])
        for key, value in table.items()
    }


def _triple_rows(
    triples: dict,
    preset: Preset,
    identities: list[dict],
    rng: np.random.Generator,
    add_mask: Callable[[np.ndarray], int],
) -> np.ndarray:
    """(t, 7): split flag (0 train, 1 test), shape, masks a, b, c, a∪b, a∪b∪c."""
    known = [i for i, m in enumerate(identities) if m["group"].startswith("known")]
    rows = []
    for packed in triples["masks"]:
        test = rng.random() < 0.15
        identity = int(rng.choice(known))
        pose = int(rng.choice(poses_for("test_a" if test else "train", "known_man", preset.poses, preset.test_poses)))
        rows.append([int(test), identity * preset.poses + pose, *[add_mask(m) for m in packed]])
    return np.array(rows, dtype=np.int64).reshape(-1, 7)
