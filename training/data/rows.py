"""The pair table being built: one column list per field and the packed masks rows point into."""

from dataclasses import dataclass, field

import numpy as np

COLUMNS = ("split", "group", "scenario", "variant", "shape_a", "shape_b", "mask_a", "mask_b", "mask_union")


@dataclass
class Rows:
    """Rows of pairs (parts A and B on shapes, their union on shape A) and the masks they index.

    Mask 0 is the whole body, the union of every full-coverage pair.
    """

    masks: list[np.ndarray]
    columns: dict[str, list] = field(default_factory=lambda: {key: [] for key in COLUMNS})

    def mask(self, packed: np.ndarray) -> int:
        """Store a packed mask; returns its index."""
        self.masks.append(packed)
        return len(self.masks) - 1

    def put(self, split: str, group: str, scenario: str, variant: str, shapes: tuple[int, int], masks: tuple) -> None:
        """One row: ``shapes`` (A's, B's), ``masks`` (A, B, union) as mask indices."""
        values = (split, group, scenario, variant, *shapes, *masks)
        for key, value in zip(COLUMNS, values, strict=True):
            self.columns[key].append(value)

    def take(self) -> dict[str, np.ndarray]:
        """The rows put so far as arrays; the writer starts empty again (its masks are kept)."""
        table = {key: np.array(value) for key, value in self.columns.items()}
        self.columns = {key: [] for key in COLUMNS}
        return table


def poses_for(split: str, group: str, poses: int, test_poses: int) -> range:
    """The poses a row of ``split`` may use: training poses for training, the held-out last
    ``test_poses`` for the known identities' tests, any pose of an identity never trained on."""
    if split == "train":
        return range(poses - test_poses)
    if group.startswith("known"):
        return range(poses - test_poses, poses)
    return range(poses)
