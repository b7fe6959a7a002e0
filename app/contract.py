"""What training writes and the service reads, defined once and imported by both sides.

The artefact file names in ``models/``, the ONNX graphs' input and output names, what the
union's ``sigma`` and the localizer's probability mean, and the spectrum definition the models
are trained on. ``training`` exports by these names and ``app`` feeds and reads by them, so a
renamed input cannot reach one side only; the definition is stamped into ``MANIFEST.json`` at
export and checked at start-up, so a model is never served spectra computed another way.
"""

from collections.abc import Collection

import numpy as np

UNION_FILE, LOCALIZER_FILE = "union.onnx", "localizer.onnx"
UNION_INPUTS = ("spectrum_a", "spectrum_b")  # float32 (batch, k), eigenvalues in 1/m², ascending
# float32 (batch, 1): the share of the smaller part's area inside the other (0 … 1), where the
# caller knows it; UNKNOWN_OVERLAP where not. Graphs exported before it have no such input.
UNION_OVERLAP_INPUT = "overlap"
UNKNOWN_OVERLAP = -1.0
# float32 (batch, 1): the boundary share, how much of the two parts' boundary length is left on
# their union's boundary (0 … 1: 0 closed, 1 neither covers any of the other's boundary), where
# the caller knows it besides the overlap; UNKNOWN_BOUNDARY where not. Read with the overlap
# only (a pair not told its overlap ignores it). Graphs exported before it have no such input.
UNION_BOUNDARY_INPUT = "boundary"
UNKNOWN_BOUNDARY = -1.0
UNION_OUTPUTS = ("union", "sigma")  # float32 (batch, k): the union's eigenvalues and their σ
LOCALIZER_INPUTS = ("spectrum",)  # float32 (batch, k)
LOCALIZER_OUTPUTS = ("probability",)  # float32 (batch, template vertices)
RECONSTRUCTION_FILE = "reconstruction.onnx"  # optional: served when present (POST /v1/reconstruct)
# optional: σ of a session's union solved on its fused registered views (app.sessions.calibration);
# without it registered sessions are not served
SESSIONS_FILE = "sessions.json"
BODY_FILE = "body.npz"  # optional: the body basis sessions are fitted with (GET /v1/sessions/{id}/body)
SEED_BODIES_FILE = "seed_bodies.npz"  # optional: the seed people's shape coefficients in that basis, at rest
# float32 (batch, k) each, 1/m²: a complete body's spectrum and its σ (all 0: a measured spectrum, not a union)
RECONSTRUCTION_INPUTS = ("spectrum", "sigma")
RECONSTRUCTION_OUTPUTS = ("vertices",)  # float32 (batch, template vertices, 3): its rest-pose body, metres
# λ₁/λ₂ above which a spectrum is of a surface with a boundary (a closed body's λ₁ is 0): the
# decoder's graph reads such a measured spectrum as a scan, and /v1/reconstruct judges its round
# trip as an open surface's (figures in training/reconstruction/decoder.py)
BOUNDARY_RATIO = 0.01
# The paper's rule, by which the card scores each localizer: a template vertex is in the region
# when the localizer's probability reaches this. The service answers by expected area instead
# (app.inference.template.localized_region).
MASK_THRESHOLD = 0.5
INTERVAL_Z = 1.6449  # σ is calibrated so that union ± INTERVAL_Z·σ holds 90 % of held-out eigenvalues
# The overlap shares tried for two operands whose share is not told (SpectralModels.union_profile,
# /v1/retrieve, the card's retrieval table): two part spectra do not tell how much the parts
# overlap, but a stored shape does, as the share under which the union comes nearest to it. Eleven
# rank as well as 21 or 41 on the card's closed two-part union queries (benchmarks/RESULTS.md,
# "share profile").
PROFILE_SHARES = np.linspace(0.0, 1.0, 11)

# The correspondence model (optional: served when present): each vertex of an uploaded part →
# its place on the template's rest pose. Inputs, for one part of n vertices, as
# app.geometry.descriptors computes them: features (n, F) float32; mass (n,) float32, m²;
# basis (n, k) float32, the part's free-boundary eigenfunctions, M-orthonormal; eigenvalues
# (k,) float32, 1/m²; neighbours (n, K) int64 and weights (n, K, 2) float32, the gradient
# stencil (app.geometry.tangent). Outputs: position (n, 3) float32, metres on the template's
# rest pose; confidence (n,) float32, the probability of the template patch it was placed in.
CORRESPONDENCE_FILE = "correspondence.onnx"
CORRESPONDENCE_INPUTS = ("features", "mass", "basis", "eigenvalues", "neighbours", "weights")
CORRESPONDENCE_OUTPUTS = ("position", "confidence")
CORRESPONDENCE_BASIS = 64  # eigenfunctions of a part the network diffuses on
HKS_TIMES = np.geomspace(2e-3, 2e-1, 12)  # m²: heat diffusion from ~4 cm to ~45 cm

# The spectrum definition: what app.geometry computes from a shape (ARCHITECTURE.md, "Spectra: the
# one definition"). Bump SPECTRUM_VERSION whenever the spectrum code changes what it computes
# (Laplacian, mass, boundary conditions, cleaning), so that models trained before are refused.
SPECTRUM_VERSION = 1
MAX_HOLE_EDGES = 8  # boundary loops up to this many edges are pin-holes, filled before the solve


def spectrum_definition() -> dict[str, int]:
    """What a model's training spectra were computed with, as stamped in ``MANIFEST.json``."""
    return {"version": SPECTRUM_VERSION, "max_hole_edges": MAX_HOLE_EDGES}


def union_feeds(
    reads: Collection[str],
    a: np.ndarray,
    b: np.ndarray,
    overlap: np.ndarray | None = None,
    boundary: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The union graph's inputs for operands of shape (batch, k), the overlap and the boundary
    share (batch values each, or None). ``reads`` is the graph's input names: a told input it
    reads but that is not given is fed unknown for every row (told nothing), so no caller fills
    it in; one given that it does not read is an error, not a hint silently lost."""
    feeds = {UNION_INPUTS[0]: a.astype(np.float32), UNION_INPUTS[1]: b.astype(np.float32)}
    told = ((UNION_OVERLAP_INPUT, overlap, UNKNOWN_OVERLAP), (UNION_BOUNDARY_INPUT, boundary, UNKNOWN_BOUNDARY))
    for name, values, unknown in told:
        if name not in reads:
            if values is not None:
                raise ValueError(f"this union graph does not read {name!r}")
            continue
        given = np.full(len(a), unknown) if values is None else values
        feeds[name] = np.asarray(given, dtype=np.float32).reshape(-1, 1)
    return feeds
