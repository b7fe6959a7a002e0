"""Held-out pairs of parts of one person, to score the overlap the correspondence model measures
and what it does for the union operator.

Two sets on identities never trained on, as the union's Test B and Test C are:

- ``pairs_b``: random region pairs (:func:`training.data.pairs.sample_pair`, partial unions and
  overlapping pairs), part B cut from the same person in another pose;
- ``pairs_c``: a scanning session's views (:func:`training.data.camera.scan_session`), paired
  as a scanner pairs them (kinds of :mod:`training.data.overlaps`): a view on the body in
  another pose, a re-scan, a close-up inside its view, consecutive and farther orbit views.

Each pair keeps both parts' correspondence inputs (the mesh as uploaded), their k = 20
spectra, the true union's spectrum (on part A's pose, as the union's benchmark computes it) and
the three template masks. A pair whose union is not one admissible region is redrawn.
"""

from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from app.geometry import GeometryError
from training.correspondence.parts import PartsPreset, part_geometry, part_of
from training.data.camera import scan_session
from training.data.overlaps import CAMERA_CLOSE_UP, CAMERA_FAR, CAMERA_NEXT, CAMERA_POSE, CAMERA_RESCAN, ORBIT
from training.data.pairs import OVERLAP, PARTIAL_UNION, sample_pair
from training.data.regions import MAX_AREA_FRACTION
from training.data.spectra import MESH, task_spectrum
from training.data.workers import mapped, run_tasks, sampler_of

PAIR_SETS = ("pairs_b", "pairs_c")
# The same draws on the training people in their training poses: what a choice made from pairs
# (whether the union is told the measured overlap) is made on, so the test pairs stay unseen.
VALIDATION_SETS = ("validation_b", "validation_c")
K = 20  # the served union operator's spectra
# A session's pairs: (kind, view of A, view of B, B in another pose); views 0…4 orbit, 5 re-scan, 6 close-up.
SESSION_PAIRS = (
    (CAMERA_POSE, 0, 0, True),
    (CAMERA_RESCAN, 0, ORBIT, False),
    (CAMERA_CLOSE_UP, ORBIT + 1, 0, False),
    (CAMERA_NEXT, 0, 1, False),
    (CAMERA_FAR, 0, 3, False),
)


def build_pairs(preset: PartsPreset, out: Path, seed: int = 0, workers: int | None = None) -> None:
    """Every pair set's draws not yet saved under ``out/pairs`` (bodies from build_parts)."""
    (out / "pairs").mkdir(exist_ok=True)
    poses = preset.poses
    unknown = range(preset.train_identities, preset.train_identities + preset.test_identities)
    people = {name: (unknown, poses) for name in PAIR_SETS}
    people |= {name: (range(preset.train_identities), poses - 1) for name in VALIDATION_SETS}
    arguments = []
    for name, (identities, usable) in people.items():
        for index in range(preset.test_pairs):
            identity = identities[index % len(identities)]
            if not pair_path(out, name, index).exists():
                arguments.append(
                    (
                        str(out / "template"),
                        str(out / "shapes.npy"),
                        str(out),
                        seed,
                        name,
                        index,
                        identity,
                        poses,
                        usable,
                    )
                )
    run_tasks(draw_pairs, arguments, lambda index, result: None, None, workers, "pairs")


def pair_path(out: Path, name: str, index: int) -> Path:
    return out / "pairs" / f"{name}-{index:05d}.npz"


@threadpool_limits.wrap(limits=1)
def draw_pairs(
    template_dir: str,
    shapes_path: str,
    out: str,
    seed: int,
    name: str,
    index: int,
    identity: int,
    poses: int,
    usable: int,
) -> None:
    """One draw of ``name``: a region pair, or a session's pairs, on ``identity`` in two of its
    first ``usable`` poses; saved as one file of rows."""
    sampler = sampler_of(template_dir)
    shapes = mapped(shapes_path)
    rng = np.random.default_rng([seed, 0xC0 + 2, (*PAIR_SETS, *VALIDATION_SETS).index(name), index])
    pose, other = (int(p) for p in rng.choice(usable, size=2, replace=False))
    shape_a, shape_b = identity * poses + pose, identity * poses + other
    body = np.asarray(shapes[shape_a], dtype=np.float64)
    if name.endswith("_b"):
        while True:
            pair = sample_pair(sampler, rng, str(rng.choice([PARTIAL_UNION, OVERLAP])))
            rows = [_row(sampler, shapes, "region", pair.a, pair.b, shape_a, shape_b)]
            if rows[0] is not None:
                break
    else:
        session = None
        while session is None:
            session = scan_session(sampler, body, rng)
        views = [*session.orbit, session.rescan, session.close_up]
        rows = [
            _row(sampler, shapes, kind, views[a], views[b], shape_a, shape_b if moved else shape_a)
            for kind, a, b, moved in SESSION_PAIRS
        ]
    kept = [row for row in rows if row is not None]
    np.savez(pair_path(Path(out), name, index), **_stacked(kept))


def _row(sampler, shapes, kind: str, a: np.ndarray, b: np.ndarray, shape_a: int, shape_b: int) -> dict | None:
    """One pair's arrays, or None when its union is no admissible region or a part cannot be solved."""
    union = a | b
    if not sampler.is_connected(union) or sampler.area_fraction(union) > MAX_AREA_FRACTION:
        return None
    body_a, body_b = (np.asarray(shapes[s], dtype=np.float64) for s in (shape_a, shape_b))
    faces = sampler.template.faces
    spectra = [task_spectrum(body, faces, mask, MESH, K) for body, mask in ((body_a, a), (body_b, b), (body_a, union))]
    if not all(np.isfinite(s).all() for s in spectra):
        return None
    try:
        inputs = [part_of(body, faces, mask, MESH)[0] for body, mask in ((body_a, a), (body_b, b))]
    except GeometryError:
        return None
    row = {"kind": kind, "spectrum_a": spectra[0], "spectrum_b": spectra[1], "union": spectra[2]}
    row |= {"mask_a": np.packbits(a), "mask_b": np.packbits(b), "mask_union": np.packbits(union)}
    for side, part in zip("ab", inputs, strict=True):
        row |= {f"{side}_{key}": value for key, value in (part.feeds() | part_geometry(part)).items()}
    return row


def _stacked(rows: list[dict]) -> dict[str, np.ndarray]:
    """Rows as one file: per-row arrays under ``<row>/<key>``, and the row count."""
    out = {"rows": np.array(len(rows))}
    for i, row in enumerate(rows):
        out |= {f"{i}/{key}": np.asarray(value) for key, value in row.items()}
    return out


def load_pairs(out: Path, name: str) -> list[dict[str, np.ndarray]]:
    """Every saved pair of set ``name``, as dicts of arrays."""
    rows = []
    for path in sorted((out / "pairs").glob(f"{name}-*.npz")):
        with np.load(path) as data:
            for i in range(int(data["rows"])):
                prefix = f"{i}/"
                rows.append({key[len(prefix) :]: data[key] for key in data.files if key.startswith(prefix)})
    return rows
