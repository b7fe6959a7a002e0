"""What a union operator is made of (:class:`UnionConfig`), a plain record so that a checkpoint
stores it as a dict and every module of the operator reads it without importing the others."""

from dataclasses import asdict, dataclass

PRIOR, MONOTONE = "prior", "monotone"  # the parametrizations of the union (UnionConfig.parametrization)


@dataclass(frozen=True)
class UnionConfig:
    k: int = 20
    neighbours: int = 4
    correction: str = "transformer"  # a key of corrections.CORRECTIONS
    parametrization: str = MONOTONE  # PRIOR: the prior corrected; MONOTONE: a decrease from min(a, b)
    coincidence_gate: bool = True  # MONOTONE only: the decrease scaled by how far apart the operands are
    # The correction also reads the operands' disjoint union (:func:`disjoint_union`), the union
    # of two parts that share nothing: the other end of the overlap range from the minimum.
    disjoint_prior: bool = False
    # The operator also reads, when a caller knows it, how much of the smaller part lies inside
    # the other (``overlap``, 0 … 1; unknown when negative, UNKNOWN_OVERLAP): two part spectra do
    # not tell how much the parts overlap (docs/decisions/006), and without it the
    # answer regresses toward the training set's typical overlap.
    overlap_hint: bool = False
    width: int = 256  # DeepSets hidden width
    # The transformers: the paper's (supplementary, "Architecture details"): T_A, which mixes the
    # two operands' tokens, 8 heads × 6 layers with a feed-forward of 64; T_B, which only
    # decodes the mixed tokens back to one value each, half as deep (3 layers, feed-forward 32).
    # Its token width is not given there; 32 (4 per head) is ours, of the size of its feed-forwards.
    embedding: int = 32
    heads: int = 8
    mixer_layers: int = 6
    mixer_feed_forward: int = 64
    decoder_layers: int = 3
    decoder_feed_forward: int = 32
    # The paper's dropout is 0.1; with the memory the correction underfits rather than overfits.
    dropout: float = 0.0
    # Width of the told specialist (ToldCorrection), the network that answers pairs told their
    # overlap; 0: none, the correction answers them too. Trained after the correction
    # (train_union.train_told), so a finished run gains one without training again.
    told_width: int = 0
    # A second told specialist answers the pairs told, besides the share, how much of the two
    # parts' boundary length is left on the union's boundary (``boundary``, 0 … 1; unknown when
    # negative, UNKNOWN_BOUNDARY). With the share it tells the union's area and boundary length,
    # the two terms of Weyl's law for a Dirichlet spectrum: a view that closes a session's holes
    # adds little area and much of the spectrum's fall, which the share alone cannot tell. A
    # network of its own, so that pairs told the share alone keep the first one's answers.
    told_boundary: bool = False

    def __post_init__(self) -> None:
        assert self.k >= 2 and self.neighbours >= 1, (self.k, self.neighbours)
        assert self.parametrization in (PRIOR, MONOTONE), self.parametrization
        assert self.embedding % self.heads == 0, "every head needs a whole share of the token"
        assert min(self.mixer_layers, self.decoder_layers) >= 1
        assert 0.0 <= self.dropout < 1.0

    def as_dict(self) -> dict:
        return asdict(self)

    @property
    def prior_rows(self) -> int:
        """Spectra the correction reads beside the operands: both kinds of prior per neighbour,
        the disjoint union if asked for, and the overlap hint's value and whether it is known."""
        return 2 * self.neighbours + int(self.disjoint_prior) + 2 * int(self.overlap_hint)
