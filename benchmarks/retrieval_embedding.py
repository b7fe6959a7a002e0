"""Whether a network trained for identity finds a person from two partial scans better than the
served ranking: issue 21's metric-learning candidate, measured.

    python benchmarks/retrieval_embedding.py [--data data/standard] [--models models] [--epochs 60]

The service ranks two operands whose union is closed by ShapeDNA distance from their predicted
union (told the share, or by share profile when not). Two learned alternatives read the two part
spectra themselves, trained on the full-coverage training pairs of the 50 training identities
(9 519 pairs; validation and test pairs never seen) and ranked against the same 630 stored
bodies by the same Euclidean distance of retrieval features (so a store would serve them
unchanged):
- **regression**: a symmetric MLP from the parts' log-spectra to the whole body's retrieval
  features (the true union of a full-coverage pair), mean squared error;
- **ranking**: the same MLP trained for identity, a softmax over the training identities' stored
  bodies at their squared distance from the output (temperature ``--temperature``), plus a
  little of the regression loss to keep the output on the features' scale.
The operator's own predicted union is not an input: its memory holds every training pair, so on
those pairs it is near exact, and a network fitted there would learn to trust it too much.

Scored on the model card's 1 773 retrieval queries (full-coverage test pairs, every group and
variant), each query's own posed shape left out, beside the served operator's untold union.
Prints a Markdown table. Seeded (torch and numpy 0); ~3 min on 2 cores.
"""

from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from app.retrieval.distance import features
from training.benchmark_arguments import benchmark_parser
from training.learning.data import PairTable, SpectralData
from training.learning.evaluate import served_predictors
from training.learning.shapedna import feature_hits, full_coverage_pairs, stored_bodies

WIDTH = 512
BATCH = 256
REGRESSION_WEIGHT = 100.0  # the ranking loss's pull to the true features, per unit of squared log error


class Ranking(NamedTuple):
    """What the ranking loss compares with: the stored bodies' features and owners, each training
    pair's person, and the softmax's temperature."""

    stored: torch.Tensor
    owner: torch.Tensor
    people: torch.Tensor
    temperature: float


class PartsToBody(nn.Module):
    """(log a, log b) → the body's retrieval features, the same for (b, a); scale-equivariant:
    the input is centred on the parts' mean log-eigenvalue and the output shifted back."""

    def __init__(self, k: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(2 * k, WIDTH), nn.GELU(), nn.Linear(WIDTH, WIDTH), nn.GELU(), nn.Linear(WIDTH, WIDTH), nn.GELU(),
            nn.Linear(WIDTH, k - 1),
        )  # fmt: skip

    def forward(self, log_a: torch.Tensor, log_b: torch.Tensor) -> torch.Tensor:
        centre = 0.5 * (log_a[:, 1:].mean(1, keepdim=True) + log_b[:, 1:].mean(1, keepdim=True))
        a, b = log_a - centre, log_b - centre
        return 0.5 * (self.net(torch.cat([a, b], 1)) + self.net(torch.cat([b, a], 1))) + centre


def log_spectra(spectra: np.ndarray) -> torch.Tensor:
    return torch.tensor(np.log(np.clip(spectra, 1e-9, None)), dtype=torch.float32)


def trained(pairs: PairTable, targets: np.ndarray, epochs: int, ranking: Ranking | None) -> PartsToBody:
    """The network fitted on ``pairs`` to ``targets`` (their bodies' features); with ``ranking``,
    for identity."""
    torch.manual_seed(0)
    model = PartsToBody(pairs.a.shape[1])
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=1e-4)
    log_a, log_b, target = log_spectra(pairs.a), log_spectra(pairs.b), torch.tensor(targets, dtype=torch.float32)
    steps = epochs * -(-len(target) // BATCH)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimizer, 1e-3, total_steps=steps)
    for _ in range(epochs):
        order = torch.randperm(len(target))
        for start in range(0, len(target), BATCH):
            rows = order[start : start + BATCH]
            out = model(log_a[rows], log_b[rows])
            loss = ((out - target[rows]) ** 2).mean()
            if ranking is not None:
                logits = -((out[:, None, :] - ranking.stored[None]) ** 2).sum(-1) / ranking.temperature
                own = ranking.owner[None, :] == ranking.people[rows, None]
                loss = (
                    REGRESSION_WEIGHT * loss
                    + (torch.logsumexp(logits, 1) - torch.logsumexp(logits.masked_fill(~own, -torch.inf), 1)).mean()
                )
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
    return model.eval()


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    parser.add_argument("--epochs", type=int, default=60)
    parser.add_argument("--temperature", type=float, default=1e-3)
    args = parser.parse_args()
    data = SpectralData(args.data)
    stored, identity = stored_bodies(data, args.models)
    train, test = full_coverage_pairs(data.pairs)
    trained_people = np.unique(identity[train.shape_a])
    unseen = ~np.isin(identity[test.shape_a], trained_people)
    stored_features = features(stored)
    known = np.flatnonzero(np.isin(identity, trained_people))
    ranking = Ranking(
        torch.tensor(stored_features[known], dtype=torch.float32),
        torch.as_tensor(identity[known]),
        torch.as_tensor(identity[train.shape_a]),
        args.temperature,
    )

    union, _ = served_predictors(args.models)
    rows = {"served operator's union, untold (ShapeDNA)": features(union(test.a, test.b)[0])}
    for name, ranked in (("regression", None), ("ranking", ranking)):
        model = trained(train, features(train.union), args.epochs, ranked)
        with torch.no_grad():
            rows[f"parts → body, {name}"] = model(log_spectra(test.a), log_spectra(test.b)).numpy()
    print(f"{len(test)} queries ({unseen.sum()} of people never trained on), {len(stored)} stored bodies")
    print("| ranked by | top-1 | top-5 | top-10 | top-1, people never trained on | mean error of the body's features |")
    print("|---|---|---|---|---|---|")
    truth = features(test.union)
    for name, query in rows.items():
        hit = feature_hits(query, test.shape_a, stored_features, identity)
        cells = " | ".join(f"{100 * rate:.1f} %" for rate in hit.mean(0))
        error = np.abs(np.expm1(query - truth)).mean()
        print(f"| {name} | {cells} | {100 * hit[unseen, 0].mean():.1f} % | {100 * error:.1f} % |")


if __name__ == "__main__":
    main()
