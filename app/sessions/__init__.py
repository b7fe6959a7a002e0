"""A scanning session's logic, free of HTTP: the views kept whole (``session``, ``records``,
``store``, ``postgres``), their union read from all of them (``reading``): fused where they share
a frame (``fused``, each view's points found on the others' by ``pairs``), aligned through their
places first where they do not (``aligned``), or the learned chain (``chain``), with σ from the
sessions' calibration (``calibration``)."""

from app.core.exports import lazy_exports

# What the training side may take from this package (``from app.sessions import Name``).
__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "aligned": ("AlignedUnion",),
        "body": ("NoBodyFits", "SessionBody", "fitted_session", "session_body", "stored_body"),
        "calibration": ("Bands", "SessionCalibration"),
        "fused": ("View", "fused_spectrum"),
        "identity": ("Candidate", "ranked_rows", "shape_distances", "unknown_warning"),
        "seen": ("SeenTemplate",),
        "session": (
            "SessionView",
            "aligned_and_chained_sigma",
            "chained_onto_aligned",
            "session_coverage",
            "session_union",
            "session_view",
        ),
        "solved": ("solved_union",),
    },
)
