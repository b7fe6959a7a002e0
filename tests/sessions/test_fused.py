"""The union of views in one frame, solved once, against analytic Dirichlet spectra of flat
rectangles (λ = π²(m²/W² + n²/H²)) and the laws a union obeys."""

from dataclasses import replace

import numpy as np
import pytest

from app.geometry.laplacian import mesh_operators
from app.geometry.shapes import Mesh
from app.geometry.spectrum import eigenpairs
from app.geometry.topology import boundary_vertex_mask
from app.sessions.fused import View, fused_cloud, fused_spectrum, view_of
from tests.conftest import grid

K = 8


def rectangle_spectrum(width: float, height: float, k: int = K) -> np.ndarray:
    m, n = np.meshgrid(np.arange(1, 12), np.arange(1, 12))
    return np.sort((np.pi**2 * ((m / width) ** 2 + (n / height) ** 2)).ravel())[:k]


def view(x0: float, x1: float, step: float, y1: float = 1.0, shift: float = 0.0) -> View:
    """A flat rectangle [x0, x1] × [0, y1] meshed at about ``step``, its vertices nudged by
    ``shift`` (two views of one surface seldom share their vertices)."""
    nx, ny = round((x1 - x0) / step), round(y1 / step)
    mesh = grid(x1 - x0, y1, nx, ny)
    points = mesh.vertices + [x0, 0.0, 0.0]
    points[:, :2] += shift * np.array([0.37, 0.61])
    operators = mesh_operators(points, mesh.faces)
    boundary = boundary_vertex_mask(mesh.faces, len(points))
    return view_of(points, operators.mass.diagonal(), boundary, mesh.faces)


def cut(mesh: Mesh, keep: np.ndarray) -> View:
    """The view of the faces of ``mesh`` whose vertices ``keep`` holds."""
    faces = mesh.faces[keep[mesh.faces].all(axis=1)]
    used = np.unique(faces)
    renumber = np.full(len(keep), -1)
    renumber[used] = np.arange(len(used))
    part = Mesh(mesh.vertices[used], renumber[faces])
    operators = mesh_operators(part.vertices, part.faces)
    boundary = boundary_vertex_mask(part.faces, len(used))
    return view_of(part.vertices, operators.mass.diagonal(), boundary, part.faces)


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.abs(a - b) / b))


def test_one_view_is_its_own_union():
    single = view(0.0, 2.0, 0.04)
    assert relative(fused_spectrum([single], K), rectangle_spectrum(2.0, 1.0)) < 0.02


def as_sent(view: View, kind: str) -> View:
    """The view as a mesh (glued through its triangles) or as a point cloud (fused as points)."""
    return view if kind == "mesh" else replace(view, faces=None)


@pytest.mark.parametrize("kind", ["mesh", "points"])
def test_two_overlapping_views_make_the_whole_rectangle(kind):
    """Left [0, 1.2] and right [0.8, 2] at other spacings: the union is [0, 2] × [0, 1], whose
    spectrum is far below either view's (a 1.2 × 1 rectangle: λ₁ 16.7 against 12.3)."""
    left, right = as_sent(view(0.0, 1.2, 0.04), kind), as_sent(view(0.8, 2.0, 0.035, shift=0.011), kind)
    union = fused_spectrum([left, right], K)
    assert relative(union, rectangle_spectrum(2.0, 1.0)) < 0.03
    assert relative(union, rectangle_spectrum(1.2, 1.0)) > 0.2


@pytest.mark.parametrize("kind", ["mesh", "points"])
def test_views_that_meet_edge_to_edge_are_joined_along_the_seam(kind):
    """[0, 1] and [1.02, 2]: the two boundaries face each other across less than a spacing, so
    the seam is inside the union, not two Dirichlet squares (λ₁ of a unit square: 19.7)."""
    left, right = as_sent(view(0.0, 1.0, 0.04), kind), as_sent(view(1.02, 2.0, 0.04), kind)
    union = fused_spectrum([left, right], K)
    assert relative(union, rectangle_spectrum(2.0, 1.0)) < 0.03
    assert union[0] < 0.75 * rectangle_spectrum(1.0, 1.0)[0]


def test_a_rescan_that_stops_where_the_first_stops_keeps_that_boundary():
    """The same rectangle twice, meshed differently: the union is the rectangle, its boundary
    where both stop (on the same side) still held at zero."""
    first, again = view(0.0, 2.0, 0.04), view(0.0, 2.0, 0.033, shift=0.004)
    assert relative(fused_spectrum([first, again], K), rectangle_spectrum(2.0, 1.0)) < 0.03


def test_a_view_inside_another_adds_nothing():
    whole, patch = view(0.0, 2.0, 0.04), view(0.5, 1.1, 0.02, y1=0.6, shift=0.2)
    alone = fused_spectrum([whole], K)
    np.testing.assert_allclose(fused_spectrum([whole, patch], K), alone, rtol=1e-9)
    np.testing.assert_allclose(fused_spectrum([patch, whole], K), alone, rtol=1e-9)


def own_spectrum(one: View) -> np.ndarray:
    """A mesh view's own Dirichlet spectrum, as its upload is solved."""
    values, _ = eigenpairs(mesh_operators(one.points, one.faces), K, one.boundary, vectors=False)
    return np.asarray(values)


def test_a_view_with_its_coarser_copy_is_the_view():
    """A part sent with its re-meshed copy (a coarser meshing of the same rectangle, its
    vertices elsewhere): each holds the other, so the union is the finer part itself, exactly,
    whichever comes first."""
    fine, coarse = view(0.0, 2.0, 0.04), view(0.0, 2.0, 0.07, shift=0.003)
    for views in ([fine, coarse], [coarse, fine]):
        np.testing.assert_allclose(fused_spectrum(views, K), own_spectrum(fine), rtol=1e-9)


def test_one_view_is_its_own_union_whatever_another_reading_says():
    """U(A) = A: the boundary of one view is what was seen. An ``inside`` rule that would free
    every boundary point is not asked, for the view alone or with a patch it holds whole."""
    whole, patch = view(0.0, 2.0, 0.04), view(0.5, 1.1, 0.02, y1=0.6, shift=0.2)

    def everything_inside(views, places, cloud):
        return np.ones(len(cloud.points), bool)

    for views in ([whole], [whole, patch]):
        places = [one.points for one in views]
        np.testing.assert_allclose(fused_spectrum(views, K, places, everything_inside), own_spectrum(whole), rtol=1e-9)


def test_views_cut_from_one_mesh_glue_back_into_it():
    """Left and right of one meshed rectangle, overlapping in the middle and sharing its
    vertices there: glued, they are the whole mesh again, and so is its spectrum."""
    mesh = grid(2.0, 1.0, 40, 20)
    whole = view_of(
        mesh.vertices,
        mesh_operators(mesh.vertices, mesh.faces).mass.diagonal(),
        boundary_vertex_mask(mesh.faces, len(mesh.vertices)),
        mesh.faces,
    )
    x = mesh.vertices[:, 0]
    left, right = cut(mesh, x <= 1.2), cut(mesh, x >= 0.8)
    np.testing.assert_allclose(fused_spectrum([left, right], K), own_spectrum(whole), rtol=1e-6)


def test_the_order_of_the_views_does_not_matter():
    parts = [view(0.0, 0.9, 0.04), view(0.7, 1.5, 0.035, shift=0.01), view(1.3, 2.0, 0.03, shift=0.02)]
    spectra = [fused_spectrum([parts[i] for i in order], K) for order in ((0, 1, 2), (2, 1, 0), (1, 0, 2))]
    for other in spectra[1:]:
        assert relative(other, spectra[0]) < 0.005


def test_a_pinhole_left_between_views_is_capped():
    """Two views that overlap everywhere but a small square gap between them (each view's notch
    at the same place): the spectrum definition caps a hole of at most 8 edges, so the union is
    the whole rectangle; the cloud says one hole was capped."""
    step = 0.05
    mesh = grid(2.0, 1.0, 40, 20)
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    notch = (np.abs(x - 1.0) < step / 2) & (np.abs(y - 0.5) < step / 2)  # one vertex: a 6-edge hole
    assert notch.sum() == 1

    left, right = cut(mesh, (x <= 1.2) & ~notch), cut(mesh, (x >= 0.8) & ~notch)
    cloud = fused_cloud([left, right])
    assert cloud.capped == 1
    assert relative(fused_spectrum([left, right], K), rectangle_spectrum(2.0, 1.0)) < 0.03


def stray_flags(whole: View, where: np.ndarray) -> View:
    """``whole`` with its points in ``where`` flagged as boundary too."""
    return replace(whole, boundary=whole.boundary | where)


def with_neighbour(flagged: View) -> list[View]:
    """``flagged`` (the left view [0, 1.2]) beside a right view [0.8, 2] meshed otherwise: the
    union is the 2 × 1 rectangle."""
    return [flagged, view(0.8, 2.0, 0.035, shift=0.011)]


def test_a_stray_boundary_point_is_no_boundary():
    """One interior point flagged (what the seam rules leave where views meet at a notch) makes
    no curve: it is freed, and the union is the rectangle."""
    left = view(0.0, 1.2, 0.04)
    centre = np.argmin(np.linalg.norm(left.points - [0.5, 0.5, 0.0], axis=1))
    stray = with_neighbour(stray_flags(left, np.arange(len(left.points)) == centre))
    cloud = fused_cloud(stray)
    assert not cloud.boundary[np.argmin(np.linalg.norm(cloud.points - left.points[centre], axis=1))]
    assert cloud.boundary.sum() == fused_cloud(with_neighbour(left)).boundary.sum()
    assert relative(fused_spectrum(stray, K), rectangle_spectrum(2.0, 1.0)) < 0.03


def test_a_slit_inside_a_view_stays_a_boundary():
    """Ten points in a row flagged are a curve (a slit): they stay on the boundary."""
    left = view(0.0, 1.2, 0.04)
    x, y = left.points[:, 0], left.points[:, 1]
    row = y[np.argmin(np.abs(y - 0.5))]
    slit = (np.abs(y - row) < 1e-9) & (x > 0.3) & (x < 0.7)
    assert slit.sum() >= 8
    cloud = fused_cloud(with_neighbour(stray_flags(left, slit)))
    assert cloud.boundary.sum() == fused_cloud(with_neighbour(left)).boundary.sum() + slit.sum()


def test_closed_views_make_a_closed_union():
    """Two caps of the unit sphere, overlapping about its equator: their union is the sphere,
    closed (λ = l(l + 1): 0, then 2 three times); with no boundary left there is nothing for
    another reading to free, and it is not asked."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    mesh = Mesh(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    z = mesh.vertices[:, 2]
    north, south = cut(mesh, z > -0.3), cut(mesh, z < 0.3)

    def not_asked(views, places, cloud):
        raise AssertionError("a closed union has no boundary to free")

    spectrum = fused_spectrum([north, south], K, [north.points, south.points], not_asked)
    assert spectrum[0] == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(spectrum[1:4], 2.0, rtol=0.03)


def sheet(x0: float, y0: float, width: float, height: float, step: float, z: float = 0.0, up: bool = True) -> Mesh:
    """A flat rectangle at height ``z`` meshed at ``step``, its normal up (+z) or down."""
    mesh = grid(width, height, round(width / step), round(height / step))
    faces = mesh.faces if up else mesh.faces[:, ::-1]
    return Mesh(mesh.vertices + [x0, y0, z], faces)


def one_view(*meshes: Mesh) -> View:
    """One scan holding ``meshes`` as its pieces."""
    points = np.concatenate([mesh.vertices for mesh in meshes])
    offsets = np.cumsum([0] + [len(mesh.vertices) for mesh in meshes[:-1]])
    faces = np.concatenate([mesh.faces + offset for mesh, offset in zip(meshes, offsets, strict=True)])
    operators = mesh_operators(points, faces)
    return view_of(points, operators.mass.diagonal(), boundary_vertex_mask(faces, len(points)), faces)


@pytest.mark.parametrize("facing", ["towards", "away"])
def test_a_stretch_across_a_gap_facing_the_other_view_is_another_surface(facing):
    """Where the body nearly touches itself (an inner thigh against the other), a view reaches
    over another's points 2 mm away, finer than their spacing. Facing them (normals apart) it
    is another stretch of the body: the union is the first view and that stretch, apart (their
    spectra merged). Facing the same way it is the same surface seen again (a re-scan's noise):
    the union is the first view. The rest of the second view lies on the first, as seen."""
    step = 0.004
    first = one_view(sheet(0.0, 0.0, 0.2, 0.1, step))
    seen_again = sheet(0.1, 0.0, 0.1, 0.1, step)
    across = sheet(0.01, 0.01, 0.08, 0.08, step, z=0.002, up=facing == "away")
    union = fused_spectrum([first, one_view(seen_again, across)], K)
    if facing == "towards":
        expected = np.sort(np.concatenate([rectangle_spectrum(0.2, 0.1), rectangle_spectrum(0.08, 0.08)]))[:K]
    else:
        expected = rectangle_spectrum(0.2, 0.1)
    assert relative(union, expected) < 0.03


def test_a_view_wound_the_other_way_round_is_the_same_surface():
    """A scan whose triangles are wound the other way (another tool's convention) turns every
    normal round: it lies on the same surface all the same, and adds nothing where it is inside
    the other view."""
    step = 0.004
    first = one_view(sheet(0.0, 0.0, 0.2, 0.1, step))
    rewound = one_view(sheet(0.1, 0.0, 0.1, 0.1, step, z=0.001, up=False))
    assert relative(fused_spectrum([first, rewound], K), rectangle_spectrum(0.2, 0.1)) < 0.03
