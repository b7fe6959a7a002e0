"""What training writes and the service reads, defined once and imported by both sides.

The artefact file names in ``models/``, the ONNX graphs' input and output names, and what the
union's ``sigma`` and the localizer's probability mean. ``training`` exports by these names and
``app`` feeds and reads by them, so a renamed input cannot reach one side only.
"""

import numpy as np

UNION_FILE, LOCALIZER_FILE = "union.onnx", "localizer.onnx"
UNION_INPUTS = ("spectrum_a", "spectrum_b")  # float32 (batch, k), eigenvalues in 1/m², ascending
UNION_OUTPUTS = ("union", "sigma")  # float32 (batch, k): the union's eigenvalues and their σ
LOCALIZER_INPUTS = ("spectrum",)  # float32 (batch, k)
LOCALIZER_OUTPUTS = ("probability",)  # float32 (batch, template vertices)
MASK_THRESHOLD = 0.5  # a template vertex is in the region when the localizer's probability reaches this
INTERVAL_Z = 1.6449  # σ is calibrated so that union ± INTERVAL_Z·σ holds 90 % of held-out eigenvalues


def union_feeds(a: np.ndarray, b: np.ndarray) -> dict[str, np.ndarray]:
    """The union graph's inputs for operands of shape (batch, k)."""
    return {UNION_INPUTS[0]: a.astype(np.float32), UNION_INPUTS[1]: b.astype(np.float32)}
