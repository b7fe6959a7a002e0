"""The correspondence network: each vertex of a part → a patch of the template, and its place.

DiffusionNet (Sharp, Attaiki, Crane, Ovsjanikov, TOG 2022), written here from the paper. Each
block mixes three things per channel and feeds them to a per-vertex MLP with a residual:
the feature itself; the feature diffused over the part for a learned time, in the part's own
eigenbasis (spectral acceleration: project with the mass, scale by exp(−λt), expand); and
spatial-gradient features, the gradient of each diffused channel in its vertex's tangent plane,
combined by a learned complex-linear map and read as Re(conj(g) · (A g)). The imaginary part
of A pairs each gradient with a rotated one, so these features change sign with the surface's
orientation: they tell left from right where nothing intrinsic can. Inputs are intrinsic and in
metres (:mod:`app.geometry.descriptors`), so neither frame nor pose changes them.

The head classifies each vertex into one of the template's patches (farthest-point samples of
the rest pose, each vertex with its nearest by edge path): a classification keeps its regions
where an uncertain regression shrinks toward the body's centroid. The place is then the
probability-weighted centre of the patches near the most probable one (it never averages a
left hand with a right one), moved by a learned offset of at most about a patch's radius: a
confident vertex would otherwise land on its patch's centre, and a part's places bunch.
"""

from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import torch
from scipy.sparse.csgraph import dijkstra
from torch import nn

from app.geometry import FEATURES
from app.inference import edge_graph


@dataclass(frozen=True)
class CorrespondenceConfig:
    features: int = FEATURES
    width: int = 64  # DiffusionNet's own experiments use 128; 64 trains ~2x faster on 2 cores
    blocks: int = 4  # the paper's default
    patches: int = 384  # ~47 cm² each on an adult: ~3.5 cm across
    neighbourhood_m: float = 0.08  # patches averaged into the place: within 8 cm of the most probable
    offset_m: float = 0.05  # the place's learned offset from the patches' weighted centre, at most (~a patch's radius)

    def as_dict(self) -> dict:
        return asdict(self)


class DiffusionBlock(nn.Module):
    """One DiffusionNet block on a single part (vertices along the first axis)."""

    def __init__(self, width: int) -> None:
        super().__init__()
        # Diffusion times from 1e-4 to 1e-1 m² (1 cm to 30 cm of spread), one per channel.
        self.log_time = nn.Parameter(torch.linspace(np.log(1e-4), np.log(1e-1), width))
        self.gradient_real = nn.Linear(width, width, bias=False)
        self.gradient_imaginary = nn.Linear(width, width, bias=False)
        self.mlp = nn.Sequential(nn.Linear(3 * width, width), nn.ReLU(), nn.Linear(width, width))

    def forward(
        self,
        x: torch.Tensor,
        mass: torch.Tensor,
        basis: torch.Tensor,
        eigenvalues: torch.Tensor,
        gradient: "BasisGradient | StencilMatrices",
    ) -> torch.Tensor:
        decay = torch.exp(-eigenvalues[:, None] * torch.exp(self.log_time)[None])
        if isinstance(gradient, StencilMatrices):  # training: the stencil applied to the diffused channels
            coefficients = decay * (basis.transpose(0, 1) @ (mass[:, None] * x))  # (k, C)
            diffused = basis @ coefficients  # (n, C)
            gx, gy = torch.sparse.mm(gradient.x, diffused), torch.sparse.mm(gradient.y, diffused)
        else:  # the exported graph: the part's operators taken once, each a product with the channels
            coefficients = decay * (gradient.projection @ x)
            diffused, gx, gy = basis @ coefficients, gradient.x @ coefficients, gradient.y @ coefficients
        bx = self.gradient_real(gx) - self.gradient_imaginary(gy)
        by = self.gradient_real(gy) + self.gradient_imaginary(gx)
        gradient_features = torch.tanh(gx * bx + gy * by)
        return x + self.mlp(torch.cat([x, diffused, gradient_features], dim=1))


class Heads(NamedTuple):
    """What the network says of each vertex: (n, patches) patch scores, (n, 3) offset in metres."""

    logits: torch.Tensor
    offset: torch.Tensor


class CorrespondenceNet(nn.Module):
    """A part's inputs (app.contract's names) → each vertex's template place and confidence."""

    def __init__(self, config: CorrespondenceConfig, centres: np.ndarray) -> None:
        super().__init__()
        self.config = config
        self.first = nn.Linear(config.features, config.width)
        self.blocks = nn.ModuleList(DiffusionBlock(config.width) for _ in range(config.blocks))
        self.head = nn.Linear(config.width, config.patches)
        self.offset = nn.Linear(config.width, 3)
        distance = np.linalg.norm(centres[:, None] - centres[None], axis=2)
        self.register_buffer("centres", torch.as_tensor(centres, dtype=torch.float32))
        self.register_buffer("near", torch.as_tensor(distance <= config.neighbourhood_m, dtype=torch.float32))

    def heads(self, features, mass, basis, eigenvalues, neighbours, weights, stencil=None) -> Heads:
        """Each vertex's patch scores and offset; ``stencil``: the gradient stencil as sparse
        matrices (:func:`stencil_matrices`), for training."""
        gradient = stencil if stencil is not None else basis_gradient(basis, mass, neighbours, weights)
        x = self.first(features)
        for block in self.blocks:
            x = block(x, mass, basis, eigenvalues, gradient)
        return Heads(self.head(x), self.config.offset_m * torch.tanh(self.offset(x)))

    def place(self, heads: Heads) -> tuple[torch.Tensor, torch.Tensor]:
        """(n, 3) place on the template and (n,) confidence: the probability-weighted centre of
        the patches near the most probable one, moved by the learned offset. Without the offset
        a confident vertex lands on its patch's centre, and a part's places bunch ~4 cm apart."""
        probability = torch.softmax(heads.logits, dim=1)
        confidence, best = probability.max(dim=1)
        local = probability * self.near[best]
        position = (local @ self.centres) / local.sum(dim=1, keepdim=True)
        return position + heads.offset, confidence

    def forward(self, features, mass, basis, eigenvalues, neighbours, weights):
        return self.place(self.heads(features, mass, basis, eigenvalues, neighbours, weights))


class StencilMatrices(NamedTuple):
    """The gradient stencil as two sparse (n, n) matrices: x and y components in the frames."""

    x: torch.Tensor
    y: torch.Tensor


def stencil_matrices(neighbours: torch.Tensor, weights: torch.Tensor) -> StencilMatrices:
    """Σ_j w_ij (f_j − f_i) as sparse matrices: w_ij at (i, neighbour j), −Σ_j w_ij on the diagonal."""
    n, width = neighbours.shape
    rows = torch.arange(n).repeat_interleave(width)
    index = torch.cat([torch.stack([rows, neighbours.reshape(-1)]), torch.arange(n).repeat(2, 1)], dim=1)

    def matrix(w: torch.Tensor) -> torch.Tensor:
        values = torch.cat([w.reshape(-1), -w.sum(dim=1)])
        return torch.sparse_coo_tensor(index, values, (n, n)).coalesce().to_sparse_csr()

    return StencilMatrices(matrix(weights[..., 0]), matrix(weights[..., 1]))


class BasisGradient(NamedTuple):
    """What the exported graph takes of a part once: the projection onto its basis with the mass
    (k, n), and the gradient stencil applied to each basis function, x and y (n, k)."""

    projection: torch.Tensor
    x: torch.Tensor
    y: torch.Tensor


def basis_gradient(
    basis: torch.Tensor, mass: torch.Tensor, neighbours: torch.Tensor, weights: torch.Tensor
) -> BasisGradient:
    """Σ_j w_ij (φ_j − φ_i) for every basis function, by gather (ONNX has no sparse product),
    and (MΦ)ᵀ.

    The stencil is linear, so the gradient of a diffused channel Φc is (∇Φ)c: the n × width
    differences, the costliest read of the exported graph, are gathered once per part (from the
    k basis functions) rather than once per block (from its channels); decision 026."""
    both = weights.transpose(1, 2) @ (basis[neighbours] - basis[:, None])  # (n, 2, k)
    return BasisGradient((mass[:, None] * basis).transpose(0, 1), both[:, 0], both[:, 1])


def template_patches(vertices: np.ndarray, faces: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) patch centres (farthest-point samples of the rest pose, from vertex 0) and
    (n,) each template vertex's patch: the centre nearest to it along the mesh's edges."""
    chosen = [0]
    distance = np.linalg.norm(vertices - vertices[0], axis=1)
    for _ in range(count - 1):
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(vertices - vertices[chosen[-1]], axis=1))
    graph = edge_graph(vertices, faces)
    _, _, sources = dijkstra(graph, indices=chosen, min_only=True, return_predecessors=True)
    patch = np.searchsorted(np.sort(chosen), sources)
    order = np.argsort(chosen)
    return vertices[np.asarray(chosen)[order]], patch
