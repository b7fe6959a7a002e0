"""How retrieval cost grows with the database: SQLite's numpy scan against PostgreSQL's GiST index.

Run: ``python -m benchmarks.bench_retrieval`` (PostgreSQL's server binaries installed, as
``.ci/run`` installs them; a throw-away server is started in a temporary folder, or give
``--postgres-url``). Each backend is filled, through the service's own store classes and in
batches of ``--batch``, to each of ``--sizes`` rows of synthetic ShapeDNA spectra: the seed
database's complete bodies (``models/shapes.npz``) each scaled as a body 5 % larger or smaller
is (all eigenvalues by 1/s²) and perturbed per eigenvalue by 2 %, as other people of similar
build would be. At each size it reports the insert rate of the last batches, the time to
rebuild PostgreSQL's GiST index over every row, and the latency of ``nearest(query, 10)`` as
the service calls it (a connection per call included) over perturbed stored spectra: p50 and
p99 of as many queries as ``--budget`` seconds allow, up to ``--queries``; and of
``nearest`` asked for a share profile's 11 spectra at once, as ``/v1/retrieve`` asks for two
operands whose overlap is not told. PostgreSQL's plan is
checked to use the index (``EXPLAIN ANALYZE``), and both backends must return the same
distances for the same rows. "first ms" is the first query after a fill: SQLite's in-memory copy
of the features reads the rows added since the last query then; "open s" is opening the filled
SQLite file afresh, as a restarted service does, which reads every row's features once
(``--backends sqlite`` alone skips the server).
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import psycopg

from app.contract import PROFILE_SHARES
from app.retrieval.distance import features
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


def postgres_index(url: str, query: np.ndarray) -> tuple[float, bool]:
    """(seconds to rebuild the GiST index, whether the k-NN plan uses it)."""
    vector = [float(x) for x in features(query)[0]]
    with psycopg.connect(url, autocommit=True) as connection:
        started = time.perf_counter()
        connection.execute("REINDEX INDEX shapes_features")
        rebuild = time.perf_counter() - started
        connection.execute("ANALYZE shapes")
        plan = connection.execute(
            "EXPLAIN ANALYZE SELECT id FROM shapes ORDER BY features <-> cube(%s::float8[]) LIMIT %s", (vector, TOP)
        ).fetchall()
    return rebuild, any("shapes_features" in row[0] for row in plan)


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
        from tests.postgres import ThrowawayPostgres  # the test suite's server, started the same way

        server = ThrowawayPostgres()
        server.start()
        url = server.url
    folder = Path(tempfile.mkdtemp(prefix="bench-retrieval-"))
    stores: dict[str, ShapeStore] = {}
    if "sqlite" in args.backends:
        stores["SQLite"] = SQLiteStore(folder / "shapes.db")
    if "postgresql" in args.backends:
        stores["PostgreSQL"] = PostgresStore(url)
    profiles = np.stack([share_profile(query) for query in queries])
    print(
        "| backend | rows | insert rows/s | GiST rebuild s | index used | open s | first ms | k-NN p50 ms | p99 ms "
        f"| queries | share profile ({len(PROFILE_SHARES)} spectra) p50 ms | p99 ms | queries |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    try:
        filled = 0
        for size in sorted(args.sizes):
            answers = {}
            for name, store in stores.items():
                rate = fill(store, rows[filled:size], args.batch)
                times = latencies(store, queries, args.budget)
                profiled = latencies(store, profiles, args.budget)
                answers[name] = [m.distance for m in store.nearest(queries[0], TOP)]
                answers[name] += [m.distance for m in store.nearest(profiles[0], TOP)]
                rebuild, used, opened = "—", "—", "—"
                if name == "SQLite":
                    started = time.perf_counter()
                    SQLiteStore(folder / "shapes.db")
                    opened = f"{time.perf_counter() - started:.1f}"
                if name == "PostgreSQL":
                    seconds, uses = postgres_index(url, queries[0])
                    rebuild, used = f"{seconds:.1f}", "yes" if uses else "NO"
                print(
                    f"| {name} | {size:,} | {rate:,.0f} | {rebuild} | {used} | {opened} | {times[0]:.1f} "
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
