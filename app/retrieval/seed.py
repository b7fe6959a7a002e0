"""The seed database: the benchmark's complete shapes, shipped compactly in ``models/``.

``models/shapes.npz`` (labels and spectra of complete bodies, written by the training
pipeline) fills a new, empty store at first start, so retrieval works out of the box; with
``models/seed_bodies.npz`` (each seed person's shape coefficients at rest, written with the body
basis), every seed shape is stored with its person's body, so identity ranks them by shape.
"""

from pathlib import Path

import numpy as np

from app.contract import SEED_BODIES_FILE
from app.retrieval.store import ShapeStore, SQLiteStore, StoredBody

SEED_FILE = "shapes.npz"
SEED_SOURCE = "seed"
AT_REST_SPREAD = 0.1  # whitened units: a seed person's coefficients are their rest body's projection


def open_store(database: Path, url: str | None, models: Path) -> ShapeStore:
    """Open (creating if needed) the store, seeding it when it is empty and a seed file exists.

    PostgreSQL when ``url`` is given (``postgresql://…``), else the SQLite file ``database``.
    """
    if url:
        from app.retrieval.postgres import PostgresStore

        store: ShapeStore = PostgresStore(url)
    else:
        store = SQLiteStore(database)
    seed = models / SEED_FILE
    if store.count() == 0 and seed.exists():
        data = np.load(seed)
        labels = [str(label) for label in data["labels"]]
        store.add_many(labels, data["spectra"].astype(np.float64), SEED_SOURCE, seed_bodies(models, labels))
    return store


def seed_bodies(models: Path, labels: list[str]) -> list[StoredBody] | None:
    """The body of each of ``labels``' person (their coefficients read at rest: spread
    :data:`AT_REST_SPREAD`), or None where ``seed_bodies.npz`` is absent or lacks one of them."""
    path = models / SEED_BODIES_FILE
    if not path.exists():
        return None
    data = np.load(path)
    by_label = dict(zip([str(label) for label in data["labels"]], data["coefficients"].astype(np.float64), strict=True))
    if not all(label in by_label for label in labels):
        return None
    return [StoredBody(by_label[label], AT_REST_SPREAD) for label in labels]
