"""Train the spectrum decoder on anny bodies, the union operator's own full-body unions and partial unions.

Rows are (spectrum, identity): every posed complete spectrum of the bodies build, and the
operator's predicted unions of the benchmark's full-coverage training pairs, predicted
leave-one-body-out as a new person's would be, so the decoder meets the union's error in
training, and the true spectra of training unions that cover half the body
or more but not all of it, so that a scanning session's union before it closes is answered
with the person's body rather than an extrapolation from complete ones; a second network learns
the measured spectra alone (the decoder's docstring says why). The union network also learns
the bodies build's scans (:mod:`training.reconstruction.unions`): every body with blind spots,
as a complete scan really arrives, and cut to partial unions. The target is always the
identity's rest-pose body. A tenth of the bodies build's identities is held out for the epoch
kept; the test identities are the benchmark's unknown ones, which neither this model nor the
union operator ever saw.
"""

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from training.common.data import SpectralData
from training.common.fit import LoopSettings, Objective, fit, seed_everything
from training.data.spectra import MESH
from training.reconstruction.bodies import BODIES_FILE
from training.reconstruction.decoder import (
    DecoderConfig,
    ShapeBasis,
    SpectrumDecoder,
    SpectrumNetwork,
    spectral_features,
)
from training.reconstruction.unions import PARTIAL_COVERAGE, SCANS_FILE, UNIONS_FILE
from training.union.net import UnionOperator
from training.union.predict import memory_rows, predict
from training.union.train import load_operator

HELD_OUT = 0.1  # of the bodies build's identities, for validation
Rows = tuple[np.ndarray, np.ndarray]  # (spectra (n, k), index into the bodies (n,))


@dataclass(frozen=True)
class DecoderTraining(LoopSettings):
    # One cosine cycle of 400 epochs (~5 min on 2 cores): 150 left the validation error at 7.5 mm,
    # 400 at 6.8; a wider, deeper network (512 × 4) did no better (6.9) and overfitted sooner.
    epochs: int = 400
    batch: int = 128
    learning_rate: float = 2e-3
    first_restart: int = 400
    patience: int = 100
    jitter: float = 0.01  # relative input noise, a pose's share of a spectrum (0.03 tried: 6.8 → 9.2 mm)
    union_rows: int = 4000  # predicted full-body unions of the benchmark's training pairs (0: none)
    # True spectra of the benchmark's training unions that cover PARTIAL_COVERAGE of the body or
    # more but not all of it (0: none): a scanning session's union before it closes (sessions
    # 147 → 81 mm, true spectra 2.8 → 2.9, two-part unions 11.4 → 11.6; model card).
    partial_rows: int = 4000
    # The bodies build's scans (`build-bodies --scans`) as rows: blind spots and partial unions
    # of 1 125 people instead of the benchmark's 45 (model card).
    body_scans: bool = True
    # The operator's unions of the bodies build's own pairs (`build-bodies --pairs`) as rows too:
    # tried, not served (true spectra 4.0 → 4.7 mm, two-part unions 11.2 → 11.2; model card).
    body_unions: bool = False


def data_set_rest_bodies(data: SpectralData) -> np.ndarray:
    """(identities, V, 3) the benchmark's identities in their rest pose (each one's first shape)."""
    shapes = np.load(data.root / "work" / "shapes.npy", mmap_mode="r")
    return np.asarray(shapes[:: data.shapes_per_identity], dtype=np.float32)


def training_people(data: SpectralData) -> np.ndarray:
    """The benchmark's identities of its training split."""
    return np.unique(data.identity_of(data.pairs.shape_a[data.pairs.split == "train"]))


def body_scan_rows(bodies_dir: Path, train_ids: np.ndarray) -> tuple[Rows, list[Rows]]:
    """The bodies build's scans: (training rows, [held-out rows of each scan kind])."""
    scans = np.load(bodies_dir / SCANS_FILE)
    spectra, body, kind = scans["spectra"], scans["body"], scans["kind"]
    seen = np.isin(body, train_ids)
    held = [~seen & (kind == k) for k in np.unique(kind)]
    return (spectra[seen], body[seen]), [(spectra[rows], body[rows]) for rows in held if rows.any()]


def union_rows(data: SpectralData, operator: UnionOperator, count: int, seed: int) -> Rows:
    """(spectra, identity) of ``count`` full-coverage training pairs' unions, as the operator
    predicts them for a body whose pairs it never saw."""
    pairs = data.pairs
    chosen = np.flatnonzero((pairs.split == "train") & (pairs.scenario == "full"))
    chosen = np.sort(np.random.default_rng(seed).choice(chosen, min(count, len(chosen)), replace=False))
    rows = pairs.rows(chosen)
    memory = pairs.rows(memory_rows(data))
    unions, _ = predict(operator, rows.a, rows.b, bodies=(memory.shape_a, rows.shape_a))
    return unions, data.identity_of(rows.shape_a)


def partial_rows(data: SpectralData, count: int, seed: int) -> Rows:
    """(spectra, identity) of ``count`` training unions covering ``PARTIAL_COVERAGE`` of the body
    or more, short of all of it, as measured: taught the person's rest body for them, the decoder
    answers a partial union with its best guess of the person instead of extrapolating from
    complete bodies (a Test C session's five views cover ~0.76 of the body)."""
    pairs = data.pairs
    candidates = np.flatnonzero((pairs.split == "train") & (pairs.mask_union != 0) & (pairs.variant == MESH))
    coverage = data.coverage(pairs.mask_union[candidates])
    chosen = candidates[coverage >= PARTIAL_COVERAGE]
    chosen = np.sort(np.random.default_rng([seed, 1]).choice(chosen, min(count, len(chosen)), replace=False))
    return pairs.union[chosen], data.identity_of(pairs.shape_a[chosen])


def body_union_rows(bodies_dir: Path, operator: UnionOperator) -> Rows:
    """(spectra, body) the operator's unions of the bodies build's pairs (``unions.npz``)."""
    pairs = np.load(bodies_dir / UNIONS_FILE)
    return predict(operator, pairs["a"], pairs["b"])[0], pairs["body"]


def _tensor(array: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(array, dtype=torch.float32)


def split_bodies(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(training, validation) identity indices of the bodies build."""
    order = np.random.default_rng(seed).permutation(count)
    held = max(1, int(round(HELD_OUT * count)))
    return np.sort(order[held:]), np.sort(order[:held])


def _rows(spectra: np.ndarray, identities: np.ndarray) -> Rows:
    """Every pose's spectrum of ``identities`` (spectra: (m, poses, k)), with its identity."""
    poses = spectra.shape[1]
    return spectra[identities].reshape(-1, spectra.shape[2]), np.repeat(identities, poses)


def vertex_error(predicted: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """(n,) mean Euclidean vertex error in metres (no alignment: same topology, same frame)."""
    return torch.linalg.vector_norm(predicted - truth, dim=-1).mean(-1)


def train_decoder(
    bodies_dir: Path,
    checkpoint: Path,
    settings: DecoderTraining,
    config: DecoderConfig,
    data: SpectralData | None = None,
    union_checkpoint: Path | None = None,
) -> SpectrumDecoder:
    """Fit the basis on the training identities, train both networks, return the decoder.

    The network for predicted unions trains on both kinds of rows and is validated on both,
    each from people it does not train on: the held-out bodies' true spectra (and the
    operator's unions of their pairs, with ``body_unions``), and the unions of held-out
    benchmark identities (a tenth of them; predicted full-body ones and true partial ones), and
    the held-out bodies' scans of each kind, each set checked on its own; the epoch kept has the
    lowest mean of those vertex errors (on true spectra alone it kept a network that never
    learned the union's error: 16 mm from two-part unions instead of 12). The network for
    measured spectra trains and is validated on the true spectra alone. ``checkpoint`` is the
    first's; the second's is beside it (``-measured``).
    """
    generator = seed_everything(settings.seed)
    arrays = np.load(bodies_dir / BODIES_FILE)
    rest, spectra = arrays["rest"].astype(np.float64), arrays["spectra"]
    train_ids, validation_ids = split_bodies(len(rest), settings.seed)
    basis = ShapeBasis.fit(rest[train_ids], config.components)
    config = replace(config, k=spectra.shape[2])
    # Row sets: training ones, and the validation checks; the measured ones first.
    training, checks = [_rows(spectra, train_ids)], [_rows(spectra, validation_ids)]
    bodies = rest
    if settings.body_scans:
        scan_rows, scan_checks = body_scan_rows(bodies_dir, train_ids)
        training.append(scan_rows)
        checks += scan_checks
    if data is not None and union_checkpoint is not None:
        operator = load_operator(data, union_checkpoint)
        if settings.body_unions:
            unions, body = body_union_rows(bodies_dir, operator)
            seen = np.isin(body, train_ids)
            training.append((unions[seen], body[seen]))
            checks.append((unions[~seen], body[~seen]))
        benchmark_rows = []
        if settings.union_rows:
            benchmark_rows.append(union_rows(data, operator, settings.union_rows, settings.seed))
        if settings.partial_rows:
            benchmark_rows.append(partial_rows(data, settings.partial_rows, settings.seed))
        people = training_people(data)
        held_people = people[split_bodies(len(people), settings.seed)[1]]
        for spectra_rows, identity in benchmark_rows:
            held = np.isin(identity, held_people)
            identity = identity + len(rest)  # the benchmark's bodies follow the build's in ``bodies``
            training.append((spectra_rows[~held], identity[~held]))
            if held.any():  # an empty check would make the mean validation error NaN
                checks.append((spectra_rows[held], identity[held]))
        if benchmark_rows:
            bodies = np.concatenate([rest, data_set_rest_bodies(data).astype(np.float64)])
    fitting = NetworkFitting(basis, bodies, settings, config, generator)
    predicted = fitting.train("decoder", training, checks, checkpoint)
    measured = fitting.train("measured", training[:1], checks[:1], checkpoint.with_stem(f"{checkpoint.stem}-measured"))
    return SpectrumDecoder(config, basis, measured, predicted).eval()


@dataclass
class NetworkFitting:
    """What both networks' training shares: the basis, the bodies rows point into, the loop."""

    basis: ShapeBasis
    bodies: np.ndarray
    settings: DecoderTraining
    config: DecoderConfig
    generator: torch.Generator

    def train(self, label: str, training: list[Rows], checks: list[Rows], checkpoint: Path) -> SpectrumNetwork:
        """A network trained on ``training`` rows, at the epoch with the lowest mean vertex
        error over the ``checks`` row sets."""
        settings, basis = self.settings, self.basis
        train_spectra = np.concatenate([rows for rows, _ in training])
        train_target = np.concatenate([target for _, target in training])
        features = spectral_features(_tensor(train_spectra)).numpy()
        network = SpectrumNetwork(self.config, features.mean(0), features.std(0))
        weights = _tensor(basis.scales**2)
        x, y = _tensor(train_spectra), _tensor(basis.coefficients(self.bodies)[train_target])
        mean, components = _tensor(basis.mean), _tensor(basis.scaled_components())
        validation = [(_tensor(rows), _tensor(self.bodies[target])) for rows, target in checks]

        def batch_loss(rows: torch.Tensor) -> torch.Tensor:
            noisy = x[rows] * (1 + settings.jitter * torch.randn(x[rows].shape, generator=self.generator))
            # The squared vertex error, up to the basis's constant residual: components are orthonormal.
            return ((network(noisy) - y[rows]).pow(2) * weights).sum(-1).mean()

        @torch.no_grad()
        def validate() -> float:
            network.eval()
            errors = [vertex_error((mean + network(query) @ components).reshape(truth.shape), truth).mean()
                      for query, truth in validation]  # fmt: skip
            return float(np.mean(errors)) * 1e3

        objective = Objective(label, len(x), batch_loss, validate, lambda mm: f"{mm:.2f} mm")
        run_config = {"model": self.config.as_dict(), "training": asdict(settings)}
        fit(network, objective, settings, checkpoint, run_config, self.generator)
        return network.eval()
