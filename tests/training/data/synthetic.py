"""A synthetic body for data-pipeline tests that must run without anny: an ellipsoid template
with 16 coordinate-band parts, an exact mirror map, and identities/poses as smooth deformations."""

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from training.data.template import PART_NAMES, Template


def synthetic_template() -> Template:
    sphere = trimesh.creation.icosphere(subdivisions=4)
    v = np.asarray(sphere.vertices) * np.array([0.25, 0.15, 0.85])
    f = np.asarray(sphere.faces, dtype=np.int64)
    _, mirror = cKDTree(v).query(v * np.array([-1.0, 1.0, 1.0]))
    band = np.clip(((v[:, 2] + 0.85) / 1.7 * 8).astype(int), 0, 7)  # 8 height bands
    central = np.array([PART_NAMES.index(p) for p in ("hips", "torso", "neck", "head")])
    sided = ("upper_arm", "forearm", "hand", "thigh", "shin", "foot")
    part = np.array([sided[(b * 2 + (abs(x) > 0.12)) % 6] for b, x in zip(band, v[:, 0], strict=True)])
    side = np.where(v[:, 0] > 0, "left", "right")
    sided_labels = np.array([PART_NAMES.index(f"{s}_{p}") for s, p in zip(side, part, strict=True)])
    labels = np.where(band >= 4, central[np.clip(band - 4, 0, 3)], sided_labels)
    return Template(v, f, labels, mirror)


class SyntheticSource:
    """Identities scale the template; poses bend it smoothly (near-isometric, like skinning)."""

    description = "synthetic test body"

    def template(self) -> Template:
        return synthetic_template()

    def shapes(self, groups, poses: int, seed: int):
        template = synthetic_template()
        out, meta = [], []
        for number, group in enumerate(groups):
            for index in range(group.count):
                rng = np.random.default_rng([seed, number, index])
                size = rng.uniform(0.9, 1.1, size=3) * (0.6 if group.name == "child" else 1.0)
                body = template.vertices * size
                posed = []
                for pose in range(poses):
                    angle = 0.0 if pose == 0 else rng.uniform(-0.4, 0.4)
                    z = body[:, 2]
                    bent = body.copy()
                    bent[:, 0] = body[:, 0] * np.cos(angle * z) - 0.0
                    bent[:, 1] = body[:, 1] + angle * 0.1 * z**2
                    posed.append(bent)
                out.append(np.stack(posed))
                meta.append({"group": group.name, "label": group.name.split("_")[-1], "phenotype": {}})
        return np.stack(out), meta
