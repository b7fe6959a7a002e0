"""Identities and poses from anny: the shapes every partial scan in the data set is cut from.

anny's gender parameter runs from 0 (male) to 1 (female): its own shape distribution picks the
boys' calibration for gender ≤ 0.5, and gender 0 is the taller body. Men and women are drawn
from the outer thirds so that the paper's man/woman rows have unambiguous labels.
"""

from dataclasses import dataclass

import numpy as np

from training.data.template import SOURCE, TOPOLOGY, CappedTopology, capped_topology

# (bone, axis, low°, high°) for the left side; the right side mirrors it (x kept, y and z negated).
POSE_RANGES: tuple[tuple[str, str, float, float], ...] = (
    ("upperarm01", "x", -60, 40),
    ("upperarm01", "y", -60, 25),
    ("upperarm01", "z", -30, 30),
    ("lowerarm01", "x", -70, 0),
    ("upperleg01", "x", -60, 20),
    ("upperleg01", "y", -10, 25),
    ("lowerleg01", "x", 0, 70),
)
CENTRAL_RANGES: tuple[tuple[str, str, float, float], ...] = (
    ("spine02", "x", -15, 15),
    ("spine02", "y", -10, 10),
    ("spine02", "z", -20, 20),
    ("neck01", "x", -20, 20),
    ("neck01", "y", -20, 20),
    ("neck01", "z", -30, 30),
)
GENDER_RANGE = {"man": (0.0, 0.3), "woman": (0.7, 1.0)}
ADULT_AGES = (18.0, 70.0)
CHILD_AGES = (3.0, 10.0)


@dataclass(frozen=True)
class Identity:
    """One body: anny phenotype values, its label (man, woman, child) and its group name."""

    phenotype: dict[str, float]
    label: str
    group: str  # e.g. "known_man", "unknown_woman", "child"


class BodyModel:
    """anny, its capped topology and its self-intersection test, loaded once per process."""

    def __init__(self) -> None:
        import anny
        from anny.utils.collision import SelfInterpenetrationModule

        self.model = anny.Anny(topology=TOPOLOGY)
        self.topology: CappedTopology = capped_topology(self.model)
        self.collisions = SelfInterpenetrationModule(self.model)
        self.bones = list(self.model.bone_labels)

    def sample_identities(self, seed: int, label: str, group: str, count: int) -> list[Identity]:
        """Realistic phenotypes from anny's calibrated distribution, conditioned on label."""
        import torch
        from anny.shape_distribution import SimpleShapeDistribution

        torch.manual_seed(seed)
        ages = CHILD_AGES if label == "child" else ADULT_AGES
        genders = GENDER_RANGE.get(label, (0.0, 1.0))
        dtype = self.model.dtype
        distribution = SimpleShapeDistribution(
            self.model,
            morphological_age_distribution=torch.distributions.Uniform(
                torch.tensor(ages[0], dtype=dtype), torch.tensor(ages[1], dtype=dtype)
            ),
            gender_distribution=torch.distributions.Uniform(
                torch.tensor(genders[0], dtype=dtype), torch.tensor(genders[1], dtype=dtype)
            ),
        )
        _, sampled = distribution.sample(count)
        return [Identity({k: float(v[i]) for k, v in sampled.items()}, label, group) for i in range(count)]

    def random_pose(self, rng: np.random.Generator) -> np.ndarray:
        """(bones, 4, 4) per-bone rotations about each bone head, world-aligned axes."""
        pose = np.tile(np.eye(4), (len(self.bones), 1, 1))
        angles: dict[str, dict[str, float]] = {}
        for bone, axis, low, high in POSE_RANGES:
            value = rng.uniform(low, high)
            angles.setdefault(f"{bone}.L", {})[axis] = value
            angles.setdefault(f"{bone}.R", {})[axis] = value if axis == "x" else -value
        for bone, axis, low, high in CENTRAL_RANGES:
            angles.setdefault(bone, {})[axis] = rng.uniform(low, high)
        for bone, axes in angles.items():
            pose[self.bones.index(bone), :3, :3] = _rotation(axes)
        return pose

    def pose(self, identity: Identity, poses: np.ndarray) -> np.ndarray:
        """(p, n_capped, 3) capped-body vertices of ``identity`` in each of ``poses``."""
        return self.topology.vertices(self._anny_vertices(identity, poses).cpu().numpy())

    def collides(self, identity: Identity, pose: np.ndarray) -> bool:
        """Whether the posed anny mesh intersects itself (such poses are rejected)."""
        vertices = self._anny_vertices(identity, pose[None])[0]
        return bool((self.collisions.detect_self_intersections(vertices) >= 0).any())

    def _anny_vertices(self, identity: Identity, poses: np.ndarray):
        """(p, n_anny, 3) torch tensor of anny's own posed vertices."""
        import torch

        count = len(poses)
        phenotype = {k: torch.full((count,), v, dtype=self.model.dtype) for k, v in identity.phenotype.items()}
        with torch.no_grad():
            return self.model(
                pose_parameters=torch.as_tensor(poses, dtype=self.model.dtype), phenotype_kwargs=phenotype
            )["vertices"]

    def valid_poses(self, identity: Identity, rng: np.random.Generator, count: int, rest_first: bool) -> np.ndarray:
        """``count`` random poses without self-intersection (the rest pose first if asked)."""
        poses = [np.tile(np.eye(4), (len(self.bones), 1, 1))] if rest_first else []
        while len(poses) < count:
            candidate = self.random_pose(rng)
            if not self.collides(identity, candidate):
                poses.append(candidate)
        return np.stack(poses)


def _rotation(axes: dict[str, float]) -> np.ndarray:
    """Rz · Ry · Rx from angles in degrees."""
    x, y, z = (np.radians(axes.get(a, 0.0)) for a in "xyz")
    rx = np.array([[1, 0, 0], [0, np.cos(x), -np.sin(x)], [0, np.sin(x), np.cos(x)]])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rz = np.array([[np.cos(z), -np.sin(z), 0], [np.sin(z), np.cos(z), 0], [0, 0, 1]])
    return rz @ ry @ rx


class AnnySource:
    """The real :class:`~training.data.build.ShapeSource`: anny identities in random valid poses."""

    description = SOURCE

    def __init__(self) -> None:
        self.body = BodyModel()

    def template(self):
        from training.data.template import build_template

        return build_template(self.body.model)

    def shapes(self, groups, poses: int, seed: int) -> tuple[np.ndarray, list[dict]]:
        vertices, meta = [], []
        for number, group in enumerate(groups):
            label = group.name.split("_")[-1]
            identities = self.body.sample_identities(seed * 100 + number, label, group.name, group.count)
            for index, identity in enumerate(identities):
                rng = np.random.default_rng([seed, number, index])
                chosen = self.body.valid_poses(identity, rng, poses, rest_first=True)
                vertices.append(self.body.pose(identity, chosen))
                meta.append({"group": group.name, "label": label, "phenotype": identity.phenotype})
        return np.stack(vertices), meta
