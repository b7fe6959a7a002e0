"""The networks that correct the memory's prior (the paper's two transformers, or DeepSets) and
the told specialist that answers pairs told their overlap; each commutes in its operands bit for
bit."""

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from training.union.config import UnionConfig


def _mlp(inputs: int, width: int, outputs: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(inputs, width), nn.GELU(), nn.Dropout(dropout), nn.Linear(width, width), nn.GELU(),
        nn.Linear(width, outputs),
    )  # fmt: skip


class DeepSetsCorrection(nn.Module):
    """Δz from the operands and the priors: φ per operand, summed, then ρ.

    The sum of the two codes is what makes it commutative: IEEE addition is, bit for bit.
    """

    def __init__(self, config: UnionConfig) -> None:
        super().__init__()
        k, n, width = config.k, config.prior_rows, config.width
        self.part = _mlp(k + n * k, width, width, config.dropout)  # φ(z(part), z(priors))
        self.head = _mlp(width + n * k + config.neighbours, width, k, config.dropout)  # ρ(Σφ, priors, distances)
        nn.init.zeros_(self.head[-1].weight)  # start at the nearest prior
        nn.init.zeros_(self.head[-1].bias)

    def forward(self, za: Tensor, zb: Tensor, priors: Tensor, distances: Tensor) -> Tensor:
        flat = priors.flatten(1)
        pooled = self.part(torch.cat([za, flat], dim=1)) + self.part(torch.cat([zb, flat], dim=1))
        return self.head(torch.cat([pooled, flat, distances], dim=1))


class ToldCorrection(nn.Module):
    """The decrease in z from the operands' minimum for a pair told its overlap: an MLP reading
    both operands, their disjoint union (z, the pair's common scale) and the share told, run in
    both operand orders and averaged.

    Why a network of its own: told the share, what two parts add to each other is nearly a
    function of their spectra and that one number, and a plain MLP of three layers learns it in a
    minute and better than the transformer correction reads it as two more rows among its tokens
    (held-out rows told their share: Test B 7.5 → 6.9 %, Test C views under a quarter shared
    10.2 → 8.4 %; model card). The two orders go through the network as one batch of 2B, and the
    halves' non-negative outputs are added: commutative bit for bit, as IEEE addition is.
    """

    def __init__(self, k: int, width: int, boundary: bool = False) -> None:
        super().__init__()
        self.told_columns = 2 if boundary else 1  # the share, and the boundary share for one that reads it
        inputs = 3 * k + self.told_columns
        # The inputs' standardization, set from the training rows (set_standardization).
        self.register_buffer("centre", torch.zeros(inputs))
        self.register_buffer("spread", torch.ones(inputs))
        self.net = nn.Sequential(
            nn.Linear(inputs, width), nn.GELU(), nn.Linear(width, width), nn.GELU(),
            nn.Linear(width, width), nn.GELU(), nn.Linear(width, k),
        )  # fmt: skip

    def told(self, overlap: Tensor, boundary: Tensor | None = None) -> Tensor:
        """(B, told_columns) what the pair is told: the share and, for a specialist that reads it,
        the boundary share, each clamped to 0 … 1."""
        share = torch.clamp(overlap, min=0.0, max=1.0)
        if self.told_columns == 1:
            return share
        assert boundary is not None, "a boundary specialist answers pairs told their boundary share"
        return torch.cat([share, torch.clamp(boundary, min=0.0, max=1.0)], 1)

    @staticmethod
    def inputs(za: Tensor, zb: Tensor, disjoint: Tensor, told: Tensor) -> Tensor:
        """(2B, 3k + told columns): the pair in both operand orders, one order per half."""
        return torch.cat([torch.cat([za, zb, disjoint, told], 1), torch.cat([zb, za, disjoint, told], 1)], 0)

    @torch.no_grad()
    def set_standardization(self, inputs: Tensor) -> None:
        """Centre and spread of each input column over ``inputs`` (what is told left as it is)."""
        self.centre.copy_(inputs.mean(0))
        self.spread.copy_(inputs.std(0).clamp(min=1e-6))
        self.centre[-self.told_columns :], self.spread[-self.told_columns :] = 0.0, 1.0

    def forward(self, za: Tensor, zb: Tensor, disjoint: Tensor, told: Tensor) -> Tensor:
        """(B, k) ≥ 0: the decrease, before the coincidence gate; ``told`` from :meth:`told`."""
        both = nn.functional.softplus(self.net((self.inputs(za, zb, disjoint, told) - self.centre) / self.spread))
        half = za.shape[0]
        return (both[:half] + both[half:]) / 2


class TransformerCorrection(nn.Module):
    """Δz by the paper's two transformers, reading the priors as well.

    A token per eigenvalue index: the operand's offset in z (z_i − z_{i−1}, the paper's offset
    encoding in relative-log space), its z, the priors' z at that index, a learned position θᵢ
    and which operand it is. T_A reads both operands' tokens and returns the first operand's,
    informed by the second; it runs in both orders and the two are summed, commutative bit for
    bit. Outside training both orders go through T_A as one batch of 2B: a third fewer nodes in
    the exported graph, batch 1 ~11 % faster in onnxruntime, and the same bits as two calls (in
    PyTorch too, on every validation pair); each row is computed alike wherever it sits in the
    batch, and the halves are added as a + b. Training keeps two calls, whose weight gradients
    the served checkpoint was trained with (one batch would sum them in another order). T_B
    decodes, with the key distances added to every token, and ρ maps each token to its Δzᵢ.
    """

    def __init__(self, config: UnionConfig) -> None:
        super().__init__()
        k, d = config.k, config.embedding
        self.k = k
        self.embed = nn.Linear(2 + config.prior_rows, d)  # offset, z, and the priors
        self.position = nn.Parameter(torch.randn(k, d) * 0.02)
        self.operand = nn.Parameter(torch.randn(2, d) * 0.02)  # self, other
        self.distance = nn.Linear(config.neighbours, d)
        self.mixer = _encoder(d, config.heads, config.mixer_layers, config.mixer_feed_forward, config.dropout)  # T_A
        self.decoder = _encoder(d, config.heads, config.decoder_layers, config.decoder_feed_forward, config.dropout)
        self.rho = nn.Linear(d, 1)
        nn.init.zeros_(self.rho.weight)  # start at the nearest prior
        nn.init.zeros_(self.rho.bias)

    def _tokens(self, z: Tensor, priors: Tensor, role: int) -> Tensor:
        offsets = torch.diff(z, dim=1, prepend=torch.zeros_like(z[:, :1]))
        features = torch.cat([offsets[..., None], z[..., None], priors.transpose(1, 2)], dim=-1)
        return self.embed(features) + self.position + self.operand[role]

    def _pair_tokens(self, first: Tensor, second: Tensor, priors: Tensor) -> Tensor:
        """(B, 2k, d): the first operand's tokens, then the second's."""
        return torch.cat([self._tokens(first, priors, 0), self._tokens(second, priors, 1)], dim=1)

    def forward(self, za: Tensor, zb: Tensor, priors: Tensor, distances: Tensor) -> Tensor:
        orders = (self._pair_tokens(za, zb, priors), self._pair_tokens(zb, za, priors))
        if self.training:
            mixed = self.mixer(orders[0])[:, : self.k] + self.mixer(orders[1])[:, : self.k]
        else:
            mixed = self.mixer(torch.cat(orders, dim=0))[:, : self.k].unflatten(0, (2, -1)).sum(0)
        decoded = self.decoder(mixed + self.distance(distances)[:, None])
        return self.rho(decoded)[..., 0]


class EncoderLayer(nn.TransformerEncoderLayer):
    """PyTorch's pre-norm encoder layer whose self-attention, outside training, is ONNX's own
    ``Attention`` operator (opset 23; ``torch.onnx.ops.attention``, whose PyTorch form is its
    reference) on the in-projection's three thirds, instead of PyTorch's general multi-head
    attention.

    Why: exported, PyTorch's attention is ~40 nodes per layer of reshapes, transposes, squeezes
    and slices, and at batch 1 onnxruntime's time is per node: one ``Split`` and one
    ``Attention`` (the heads split inside the operator) leave the union graph ~200 nodes smaller
    and faster at every batch size (`benchmarks/RESULTS.md`), computing the same to float32
    rounding (`tests/training/union/test_models.py` compares the two). Training keeps
    PyTorch's own attention, whose gradients the served checkpoint was trained with; so do
    masks, which the operator never passes.
    """

    def _sa_block(
        self, x: Tensor, attn_mask: Tensor | None, key_padding_mask: Tensor | None, is_causal: bool = False
    ) -> Tensor:
        if self.training or attn_mask is not None or key_padding_mask is not None:
            return super()._sa_block(x, attn_mask, key_padding_mask, is_causal)
        attention = self.self_attn
        heads = attention.num_heads
        q, k, v = F.linear(x, attention.in_proj_weight, attention.in_proj_bias).chunk(3, dim=-1)
        mixed = torch.onnx.ops.attention(q, k, v, q_num_heads=heads, kv_num_heads=heads)[0]
        return self.dropout1(F.linear(mixed, attention.out_proj.weight, attention.out_proj.bias))


def _encoder(width: int, heads: int, layers: int, feed_forward: int, dropout: float) -> nn.TransformerEncoder:
    layer = EncoderLayer(width, heads, feed_forward, dropout, activation="gelu", batch_first=True, norm_first=True)
    return nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)


CORRECTIONS = {"deepsets": DeepSetsCorrection, "transformer": TransformerCorrection}
