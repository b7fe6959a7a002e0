"""Geometry: parse uploads, validate them, and compute their truncated Laplace–Beltrami spectra.

Nothing here knows about HTTP, torch or anny, so the service, the CLI and the training
package all compute spectra through this one code path.
"""

from app.core.exports import lazy_exports

# What the training side may take from this package (``from app.geometry import Name``).
__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "descriptors": ("BOUNDARY_COLUMN", "FEATURES", "PartInputs", "cloud_inputs", "mesh_inputs"),
        "errors": ("GeometryError",),
        "laplacian": ("mesh_operators", "point_cloud_operators"),
        "pipeline": ("Solved", "SpectrumOptions", "cloud_spectrum", "mesh_spectrum", "solve_bytes"),
        "placing": ("Part", "cloud_part", "mesh_part"),
        "shapes": ("Mesh", "PointCloud"),
        "spectrum": ("eigenpairs",),
        "topology": (
            "boundary_half_edges",
            "boundary_loops",
            "boundary_vertex_mask",
            "cap_faces",
            "drop_unreferenced",
            "face_areas",
            "referenced",
        ),
        "validate": ("prepare_cloud", "prepare_mesh"),
    },
)
