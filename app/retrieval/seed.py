"""The seed database: the benchmark's complete shapes, shipped compactly in ``models/``.

``models/shapes.npz`` (labels and spectra of complete bodies, written by the training
pipeline) fills a new, empty store at first start, so retrieval works out of the box.
"""

from pathlib import Path

import numpy as np

from app.retrieval.store import ShapeStore, SQLiteStore

SEED_FILE = "shapes.npz"
SEED_SOURCE = "seed"


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
        store.add_many([str(label) for label in data["labels"]], data["spectra"].astype(np.float64), SEED_SOURCE)
    return store
