"""How retrieval cost grows with the database, on SQLite and PostgreSQL.

Run: ``python -m benchmarks.bench_retrieval`` (PostgreSQL's server binaries installed, as
``.ci/run`` installs them; a throw-away server is started in a temporary folder, or give
``--postgres-url``; ``--backends sqlite`` alone skips the server). Each backend is filled,
through the service's own store classes and in batches of ``--batch``, to each of ``--sizes``
rows of synthetic ShapeDNA spectra: the seed database's complete bodies (``models/shapes.npz``)
each scaled as a body 5 % larger or smaller is (all eigenvalues by 1/s²) and perturbed per
eigenvalue by 2 %, as other people of similar build would be. At each size it reports the insert
rate of the last batches, "open s" (a fresh store on the filled database, as a restarted replica
opens it: it reads every row's features once), "first ms" (the first query after the fill, when
the store's in-memory copy reads the rows added since its last query), "after a deletion ms" (the
first query after one row of the fill, not the newest, was deleted: the copy reads the deletion
log; that row stays deleted, so each size holds one row less per size before it), and the latency of
``nearest(query, 10)`` as the service calls it over perturbed stored spectra: p50 and p99 of as
many queries as ``--budget`` seconds allow, up to ``--queries``; and of ``nearest`` asked for a
share profile's 11 spectra at once, as ``/v1/retrieve`` asks for two operands whose overlap is
not told. Both backends must return the same distances for the same rows.
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from app.contract import PROFILE_SHARES
from app.retrieval.postgres import PostgresStore
from app.retrieval.seed import SEED_FILE
from app.retrieval.store import ShapeStore, SQLiteStore

SIZE_SPREAD = 0.05  # relative spread of body size (eigenvalues scale by 1/size²)
SHAPE_SPREAD = 0.02  # relative spread of each eigenvalue around its body's
TOP = 10


def synthetic_spectra(seed: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` spectra like other people's: stored bodies resized and perturbed, sorted again."""
    base = seed[rng.integers(len(seed), size=count)]
    size = np.exp(rng.normal(0.0, SIZE_SPREAD, (count, 1)))
    shape = np.exp(rng.normal(0.0, SHAPE_SPREAD, base.shape))
    return np.sort(base / size**2 * shape, axis=1)


def fill(store: ShapeStore, spectra: np.ndarray, batch: int) -> float:
    """Insert ``spectra`` in batches; rows per second over the last (up to) ten batches."""
    seconds, rows = [], []
    for start in range(0, len(spectra), batch):
        chunk = spectra[start : start + batch]
        started = time.perf_counter()
        store.add_many([f"synthetic-{start + i}" for i in range(len(chunk))], chunk, "benchmark")
        seconds.append(time.perf_counter() - started)
        rows.append(len(chunk))
    return sum(rows[-10:]) / sum(seconds[-10:]) if seconds else float("nan")


def share_profile(query: np.ndarray) -> np.ndarray:
    """(len(PROFILE_SHARES), k) spectra standing for a query's share profile (``/v1/retrieve``
    with two operands untold asks ``nearest`` for all of them at once): the query lowered by up
    to 30 % along the shares, as a union's eigenvalues fall the more the parts add."""
    return np.stack([query * (1 - 0.3 * share) for share in PROFILE_SHARES])


def latencies(store: ShapeStore, queries: np.ndarray, budget: float) -> list[float]:
    """Milliseconds per ``nearest`` call, for as many queries as the budget allows (at least 3);
    ``queries`` (n, k), or (n, m, k) for calls with m spectra each."""
    out: list[float] = []
    deadline = time.perf_counter() + budget
    for query in queries:
        started = time.perf_counter()
        store.nearest(query, TOP)
        out.append(1e3 * (time.perf_counter() - started))
        if len(out) >= 3 and time.perf_counter() > deadline:
            break
    return out


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def reopen(name: str, folder: Path, url: str | None) -> ShapeStore:
    """A fresh store on the backend's database, as a restarted replica opens it."""
    return SQLiteStore(folder / "shapes.db") if name == "SQLite" else PostgresStore(url)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--queries", type=int, default=200)
    parser.add_argument("--budget", type=float, default=60.0, help="seconds of queries per backend and size")
    parser.add_argument("--batch", type=int, default=10_000)
    parser.add_argument("--models", type=Path, default=Path("models"))
    parser.add_argument("--postgres-url", default=None, help="an empty database; default: a throw-away server")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--backends", nargs="+", choices=["sqlite", "postgresql"], default=["sqlite", "postgresql"])
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    seed = np.load(args.models / SEED_FILE)["spectra"].astype(np.float64)
    rows = synthetic_spectra(seed, max(args.sizes), rng)
    queries = synthetic_spectra(seed, args.queries, rng)
    server = None
    url = args.postgres_url
    if url is None and "postgresql" in args.backends:
        from harness.postgres import ThrowawayPostgres  # the test suite's server, started the same way

        server = ThrowawayPostgres()
        server.start()
        url = server.url
    folder = Path(tempfile.mkdtemp(prefix="bench-retrieval-"))
    names = {"sqlite": "SQLite", "postgresql": "PostgreSQL"}
    stores = {names[backend]: reopen(names[backend], folder, url) for backend in args.backends}
    profiles = np.stack([share_profile(query) for query in queries])
    print(
        "| backend | rows | insert rows/s | open s | first ms | after a deletion ms | k-NN p50 ms | p99 ms "
        f"| queries | share profile ({len(PROFILE_SHARES)} spectra) p50 ms | p99 ms | queries |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    try:
        filled = 0
        for size in sorted(args.sizes):
            answers = {}
            for name, store in stores.items():
                rate = fill(store, rows[filled:size], args.batch)
                first = latencies(store, queries[-1:], 0)[0]  # the copy reads the rows just added
                times = latencies(store, queries, args.budget)
                profiled = latencies(store, profiles, args.budget)
                answers[name] = [m.distance for m in store.nearest(queries[0], TOP)]
                answers[name] += [m.distance for m in store.nearest(profiles[0], TOP)]
                victim = store.nearest(rows[(filled + size) // 2], 1)[0].record  # a row of this fill, itself
                store.delete(victim.id)
                deleted = latencies(store, queries[:1], 0)[0]  # the copy reads the deletion
                started = time.perf_counter()
                reopen(name, folder, url)
                opened = time.perf_counter() - started
                print(
                    f"| {name} | {size:,} | {rate:,.0f} | {opened:.1f} | {first:.1f} | {deleted:.1f} "
                    f"| {percentile(times, 50):.1f} | {percentile(times, 99):.1f} | {len(times)} "
                    f"| {percentile(profiled, 50):.1f} | {percentile(profiled, 99):.1f} | {len(profiled)} |",
                    flush=True,
                )
            filled = size
            if len(answers) == 2 and not np.allclose(*answers.values(), rtol=1e-9, atol=1e-9):
                raise SystemExit(f"the backends disagree at {size} rows: {answers}")
    finally:
        if server is not None:
            server.remove()


if __name__ == "__main__":
    main()
