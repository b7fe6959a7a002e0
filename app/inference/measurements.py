"""Body measurements on a rest-pose body in the template's topology, named as ISO 8559-1 names them.

Every body the service rebuilds or fits shares the template's vertices, so a measurement is
defined once on the template: the landmarks are template vertices found from its part labels
(where two parts meet), the girths horizontal slices of the torso at heights set by them, as a
tape measure takes them (the convex hull of the slice: the tape bridges hollows). How each is
taken, and where it departs from the standard's wording, is in ``docs/measurements.md``.

What a session did not see it cannot measure: each measurement names the body parts it rests
on, and a caller leaves out the ones whose parts were not seen (:data:`NEEDS`).
"""

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from app.inference.template import PART_NAMES, Template

UP = 2  # the template stands along z
SIDES = ("left", "right")
CHEST_BELOW_ARMPIT = 0.015  # of stature: the chest girth is taken just below the armpits, clear of the arms
HIP_ABOVE_CROTCH = 0.02  # of stature: the hip girth is sought from just above the crotch …
SHOULDER_BAND_M = 0.02  # the template's shoulder outline is read in bands this wide …
SHOULDER_SLOPE = np.tan(np.radians(35))  # … and turns down the arm where it falls this steeply
SLICE_STEP = 0.005  # of stature: … to the waist, and the waist between hips and chest, at this step

# The body parts each measurement rests on (any one group of a tuple of groups will do).
NEEDS: dict[str, tuple[tuple[str, ...], ...]] = {
    "stature": (("head", "left_foot"), ("head", "right_foot")),
    "chest_girth": (("torso",),),
    "waist_girth": (("torso", "hips"),),
    "hip_girth": (("hips",),),
    "crotch_height": tuple(("hips", f"{side}_thigh", f"{side}_shin", f"{side}_foot") for side in SIDES),
    "arm_length": tuple((f"{side}_upper_arm", f"{side}_forearm", f"{side}_hand") for side in SIDES),
    "shoulder_breadth": (("torso", "left_upper_arm", "right_upper_arm"),),
}
MEASUREMENTS = tuple(NEEDS)


@dataclass(frozen=True)
class Landmarks:
    """Template vertices the measurements are taken at: the crotch (the lowest point of the hips
    on the midline), each side's armpit (the lowest point where torso and upper arm meet) and
    shoulder point (the highest), and each side's elbow and wrist rings (where upper arm and
    forearm, forearm and hand meet)."""

    crotch: int
    armpit: tuple[int, int]
    shoulder: tuple[int, int]
    elbow: tuple[np.ndarray, np.ndarray]
    wrist: tuple[np.ndarray, np.ndarray]
    torso: np.ndarray  # (V,) the vertices a torso girth may pass through: torso and hips

    @classmethod
    def of(cls, template: Template) -> "Landmarks":
        vertices, labels = template.vertices, template.labels
        part = {name: index for index, name in enumerate(PART_NAMES)}
        hips = np.flatnonzero(labels == part["hips"])
        midline = hips[np.abs(vertices[hips, 0] - np.median(vertices[:, 0])) < _spacing(template)]
        crotch = int(midline[np.argmin(vertices[midline, UP])])
        armpit, shoulder, elbow, wrist = [], [], [], []
        for side in SIDES:
            seam = _seam(template, part["torso"], part[f"{side}_upper_arm"])
            armpit.append(int(seam[np.argmin(vertices[seam, UP])]))
            shoulder.append(_shoulder_point(template, part[f"{side}_upper_arm"], seam))
            elbow.append(_seam(template, part[f"{side}_upper_arm"], part[f"{side}_forearm"]))
            wrist.append(_seam(template, part[f"{side}_forearm"], part[f"{side}_hand"]))
        torso = np.isin(labels, [part["torso"], part["hips"]])
        return cls(crotch, tuple(armpit), tuple(shoulder), tuple(elbow), tuple(wrist), torso)


def _seam(template: Template, a: int, b: int) -> np.ndarray:
    """Vertices of part ``a`` with a neighbour in part ``b``."""
    edges = np.concatenate([template.faces[:, [0, 1]], template.faces[:, [1, 2]], template.faces[:, [2, 0]]])
    labels = template.labels
    across = edges[(labels[edges[:, 0]] == a) & (labels[edges[:, 1]] == b)]
    seam = np.unique(across[:, 0])
    if len(seam) == 0:
        raise ValueError(f"parts {PART_NAMES[a]} and {PART_NAMES[b]} do not meet on this template")
    return seam


def _shoulder_point(template: Template, arm: int, seam: np.ndarray) -> int:
    """The shoulder point (acromion) of one side: along the top outline of torso and upper
    arm seen from the front (the highest vertex in each band of SHOULDER_BAND_M across), going
    outward from the neck, the last vertex before the outline turns down the arm, steeper than
    35° from one band to the next."""
    vertices, labels = template.vertices, template.labels
    outward = np.sign(vertices[labels == arm, 0].mean() - np.median(vertices[:, 0]))
    across = outward * vertices[:, 0]
    start = across[seam].min()
    region = np.flatnonzero((labels == PART_NAMES.index("torso")) | (labels == arm))
    region = region[across[region] >= start]
    band = np.floor((across[region] - start) / SHOULDER_BAND_M).astype(int)
    top = [region[band == b][np.argmax(vertices[region[band == b], UP])] for b in np.unique(band)]
    for here, further in zip(top, top[1:], strict=False):
        rise = vertices[further, UP] - vertices[here, UP]
        if rise < -SHOULDER_SLOPE * (across[further] - across[here]):
            return int(here)
    raise ValueError("the template's shoulder outline never turns down the arm")


def _spacing(template: Template) -> float:
    """The template's median edge length."""
    faces = template.faces
    return float(np.median(np.linalg.norm(template.vertices[faces[:, 0]] - template.vertices[faces[:, 1]], axis=1)))


def girth(vertices: np.ndarray, faces: np.ndarray, height: float, through: np.ndarray, midline: float) -> float | None:
    """The tape girth of the body at ``height``: the perimeter of the convex hull of the closed
    slice through the faces of ``through`` (V,) vertices that crosses the ``midline`` (x); None
    where no slice there does."""
    z = vertices[:, UP]
    inside = through[faces].all(axis=1)
    below = z[faces] < height
    crossing = faces[inside & (below.sum(axis=1) % 3 != 0)]
    if len(crossing) == 0:
        return None
    # Each crossing face cuts two of its edges; a cut point is named by its edge, so that
    # neighbouring faces' segments join exactly.
    cuts = []
    for first, second in ((0, 1), (1, 2), (2, 0)):
        a, b = crossing[:, first], crossing[:, second]
        cut = (z[a] < height) != (z[b] < height)
        cuts.append(np.where(cut[:, None], np.sort(np.column_stack([a, b]), axis=1), -1))
    edge_ids, points = _cut_points(vertices, crossing, cuts, height)
    pair = np.stack([edge_ids[0], edge_ids[1]], axis=1)
    count = len(points)
    graph = coo_matrix((np.ones(len(pair)), (pair[:, 0], pair[:, 1])), shape=(count, count))
    _, component = connected_components(graph, directed=False)
    best = None
    for loop in np.unique(component):
        outline = points[component == loop][:, :2]
        if len(outline) < 3 or not outline[:, 0].min() < midline < outline[:, 0].max():
            continue
        try:
            perimeter = ConvexHull(outline).area  # a 2-D hull's "area" is its perimeter
        except QhullError:
            continue
        best = perimeter if best is None else max(best, perimeter)
    return best


def _cut_points(
    vertices: np.ndarray, faces: np.ndarray, cuts: list[np.ndarray], height: float
) -> tuple[list[np.ndarray], np.ndarray]:
    """Each crossing face's two cut points as indices into the (m, 3) points where the slice
    crosses an edge (one point per edge, whichever face cut it)."""
    per_face = np.stack(cuts, axis=1)  # (f, 3 edges, 2 vertices), -1 where the edge is not cut
    cut = per_face[:, :, 0] >= 0
    edges = per_face[cut]
    unique, index = np.unique(edges, axis=0, return_inverse=True)
    a, b = vertices[unique[:, 0]], vertices[unique[:, 1]]
    t = (height - a[:, UP]) / (b[:, UP] - a[:, UP])
    points = a + t[:, None] * (b - a)
    slots = np.full(cut.shape, -1)
    slots[cut] = index.ravel()
    ordered = np.sort(slots, axis=1)[:, 1:]  # each face cuts exactly two edges
    return [ordered[:, 0], ordered[:, 1]], points


@dataclass(frozen=True)
class Measurer:
    """The measurements of bodies in one template's topology."""

    template: Template
    landmarks: Landmarks

    @classmethod
    def of(cls, template: Template) -> "Measurer":
        return cls(template, Landmarks.of(template))

    def measure(self, vertices: np.ndarray) -> dict[str, float | None]:
        """Every measurement of a rest-pose body (V, 3), metres; None where the body's shape
        leaves it undefined (a slice that finds no torso)."""
        taken = {
            "stature": self._stature(vertices),
            "crotch_height": self._crotch_height(vertices),
            "arm_length": self._arm_length(vertices),
            "shoulder_breadth": self._shoulder_breadth(vertices),
        } | self._girths(vertices)
        return {name: taken[name] for name in MEASUREMENTS}

    def _stature(self, vertices: np.ndarray) -> float:
        return float(np.ptp(vertices[:, UP]))

    def _crotch_height(self, vertices: np.ndarray) -> float:
        return float(vertices[self.landmarks.crotch, UP] - vertices[:, UP].min())

    def _shoulder_breadth(self, vertices: np.ndarray) -> float:
        left, right = self.landmarks.shoulder
        return float(np.linalg.norm(vertices[left] - vertices[right]))

    def _arm_length(self, vertices: np.ndarray) -> float:
        """Shoulder point to the wrist's centre through the elbow's, the mean of both arms."""
        lengths = []
        for shoulder, elbow, wrist in zip(
            self.landmarks.shoulder, self.landmarks.elbow, self.landmarks.wrist, strict=True
        ):
            a, b, c = vertices[shoulder], vertices[elbow].mean(axis=0), vertices[wrist].mean(axis=0)
            lengths.append(np.linalg.norm(b - a) + np.linalg.norm(c - b))
        return float(np.mean(lengths))

    def _torso_girth(self, vertices: np.ndarray, height: float) -> float | None:
        midline = float(vertices[self.landmarks.crotch, 0])
        return girth(vertices, self.template.faces, height, self.landmarks.torso, midline)

    def _girths(self, vertices: np.ndarray) -> dict[str, float | None]:
        """The chest girth just below the armpits; the hip girth, the largest from just above the
        crotch to halfway to the chest; the waist girth, the smallest between the hip girth's
        height and the chest's. Each slice at a step of SLICE_STEP of stature, taken once."""
        stature = self._stature(vertices)
        crotch = float(vertices[self.landmarks.crotch, UP])
        chest = min(vertices[i, UP] for i in self.landmarks.armpit) - CHEST_BELOW_ARMPIT * stature
        step = SLICE_STEP * stature
        hips = np.arange(crotch + HIP_ABOVE_CROTCH * stature, (crotch + chest) / 2, step)
        found = [(g, float(h)) for h in hips if (g := self._torso_girth(vertices, float(h))) is not None]
        hip, hip_height = max(found) if found else (None, crotch)
        waist_heights = np.arange(hip_height + step, chest, step)
        waists = [g for h in waist_heights if (g := self._torso_girth(vertices, float(h))) is not None]
        return {
            "chest_girth": self._torso_girth(vertices, chest),
            "waist_girth": min(waists) if waists else None,
            "hip_girth": hip,
        }


def supported(name: str, coverage: dict[str, float], least: float) -> bool:
    """Whether a session whose body parts were seen as ``coverage`` (share of each part) supports
    measurement ``name``: every part of one of its groups seen at least ``least``."""
    return any(all(coverage.get(part, 0.0) >= least for part in group) for group in NEEDS[name])
