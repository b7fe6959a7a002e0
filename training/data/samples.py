"""Real files of some test parts, so the service can be exercised end to end.

For a few test rows per group: parts A and B as PLY meshes (original and re-meshed) and as
PLY point clouds with a ``boundary`` vertex property, plus ``samples.json`` listing each file
with the spectrum the data set holds for it.
"""

import json
from pathlib import Path

import numpy as np

from app.geometry import Mesh, PointCloud
from training.data.spectra import CLOUD, MESH, REMESHED, as_point_cloud, region_mesh, remeshed


def mesh_ply(mesh: Mesh) -> bytes:
    """Binary little-endian PLY with double coordinates (so spectra reproduce exactly)."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(mesh.vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {len(mesh.faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    faces = np.zeros(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"], faces["v"] = 3, mesh.faces
    return header + mesh.vertices.astype("<f8").tobytes() + faces.tobytes()


def cloud_ply(cloud: PointCloud) -> bytes:
    """Binary PLY of points with a ``boundary`` uchar property (1 = boundary point)."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(cloud.points)}\nproperty double x\nproperty double y\nproperty double z\n"
        "property uchar boundary\nend_header\n"
    ).encode()
    rows = np.zeros(len(cloud.points), dtype=[("p", "<f8", (3,)), ("b", "u1")])
    rows["p"] = cloud.points
    rows["b"] = np.zeros(len(cloud.points)) if cloud.boundary is None else cloud.boundary
    return header + rows.tobytes()


def export_samples(out: Path, data: dict, shapes: np.ndarray, faces: np.ndarray, per_group: int = 2) -> list[dict]:
    """Write sample files under ``out/samples`` and return their index."""
    folder = out / "samples"
    folder.mkdir(exist_ok=True)
    n = len(shapes[0])
    index = []
    chosen = _sample_rows(data, per_group)
    for row in chosen:
        for part in ("a", "b"):
            shape = int(data[f"shape_{part}"][row])
            mask = np.unpackbits(data["masks"][data[f"mask_{part}"][row]], count=n).astype(bool)
            mesh = region_mesh(np.asarray(shapes[shape], dtype=np.float64), faces, mask)
            stem = f"{data['split'][row]}-{data['group'][row]}-row{row}-{part}"
            files = {
                MESH: (f"{stem}.ply", mesh_ply(mesh)),
                REMESHED: (f"{stem}-remeshed.ply", mesh_ply(remeshed(mesh))),
                CLOUD: (f"{stem}-points.ply", cloud_ply(as_point_cloud(mesh))),
            }
            for variant, (name, payload) in files.items():
                (folder / name).write_bytes(payload)
                mask_index = int(data[f"mask_{part}"][row])
                index.append(
                    {
                        "file": name,
                        "variant": variant,
                        "shape": shape,
                        "mask": mask_index,
                        "eigenvalues": _stored(data, shape, mask_index, variant),
                    }
                )
    (folder / "samples.json").write_text(json.dumps(index, indent=1))
    return index


def _stored(data: dict, shape: int, mask: int, variant: str) -> list[float] | None:
    """The data set's spectrum of this (shape, mask, variant), if it computed one."""
    match = np.flatnonzero(
        (data["spectrum_shape"] == shape) & (data["spectrum_mask"] == mask) & (data["spectrum_variant"] == variant)
    )
    return data["spectra"][match[0]].tolist() if len(match) else None


def _sample_rows(data: dict, per_group: int) -> list[int]:
    rows = []
    test = np.isin(data["split"], ["test_a", "test_b"]) & (data["variant"] == MESH)
    for group in np.unique(data["group"][test]):
        rows.extend(np.flatnonzero(test & (data["group"] == group))[:per_group].tolist())
    return rows
