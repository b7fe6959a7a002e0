"""What the service does with spectra: the ONNX union operator and localizer, and the template."""

from app.core.exports import lazy_exports

# What the training side may take from this package (``from app.inference import Name``).
__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "body": ("body_height", "spectrum_gap", "surface_area"),
        "bodyfit": ("BodyBasis", "FittedBody"),
        "correspondence": ("CorrespondenceModel", "Placement", "TELL_BELOW_KEY", "UNCERTAIN_BELOW_KEY"),
        "cover": ("Cover",),
        "manifest": ("write_manifest",),
        "measurements": ("MEASUREMENTS", "Measurer"),
        "models": (
            "SpectralModels",
            "UnionEstimate",
            "chained_sigma",
            "graph_inputs",
            "reads_boundary",
            "reads_overlap",
        ),
        "nesting": ("NESTED_BELOW_KEY", "NESTED_OVERLAP", "Nesting", "inner_confidence"),
        "template": (
            "PART_NAMES",
            "RegionBoundaries",
            "SIDED_PARTS",
            "Template",
            "boundary_share",
            "edge_graph",
            "faces_inside",
            "localized_region",
            "part_coverage",
            "turned_towards",
        ),
    },
)
