"""Identity retrieval: a ShapeDNA database of complete shapes, queried by spectrum."""

from app.core.exports import lazy_exports

# What the training side may take from this package (``from app.retrieval import Name``).
__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "distance": ("distances", "features", "nearest_of"),
        "seed": ("AT_REST_SPREAD", "SEED_FILE", "seed_bodies"),
        "store": ("StoredBodies",),
    },
)
