"""Views sent in their own frames, brought into one through their places: on a curved surface
with no symmetry, views moved by random rigid motions come back where they were (against the
motions themselves), their fused union is the registered views' union, and views of two poses,
which no rigid motion joins, are left unaligned."""

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from app.geometry.laplacian import mesh_operators
from app.geometry.shapes import Mesh
from app.geometry.topology import boundary_vertex_mask, drop_unreferenced
from app.sessions.aligned import aligned_union, aligned_views, rigid_fit
from app.sessions.fused import View, fused_spectrum, view_of
from tests.conftest import bumpy_patch

K = 8
PLACE_NOISE_M = 0.01  # the correspondence model's places are a few cm off; here, 1 cm


def surface() -> Mesh:
    """A bumpy patch about 2 m across, finely meshed (~1.5 cm spacing)."""
    return bumpy_patch(seed=3, n=9000)


def cut(mesh: Mesh, keep: np.ndarray) -> tuple[View, np.ndarray]:
    """The part of ``mesh`` whose faces lie in ``keep``, as a view, and its vertices' indices."""
    faces = mesh.faces[keep[mesh.faces].all(axis=1)]
    used = np.unique(faces)
    vertices, renumbered = drop_unreferenced(mesh.vertices, faces)
    mass = mesh_operators(vertices, renumbered).mass.diagonal()
    return view_of(vertices, mass, boundary_vertex_mask(renumbered, len(vertices)), renumbered), used


def three_views() -> tuple[list[View], list[np.ndarray]]:
    """Three overlapping views of the surface, and each point's place: its position, a little off."""
    mesh = surface()
    x = mesh.vertices[:, 0]
    rng = np.random.default_rng(0)
    views, places = [], []
    for low, high in ((-1.0, 0.2), (-0.3, 0.6), (0.3, 1.0)):
        view, used = cut(mesh, (x >= low) & (x <= high))
        views.append(view)
        places.append(mesh.vertices[used] + rng.normal(scale=PLACE_NOISE_M / np.sqrt(3), size=(len(used), 3)))
    return views, places


def moved(views: list[View], seed: int) -> tuple[list[View], list]:
    rng = np.random.default_rng(seed)
    motions = [(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3)) for _ in views]
    out = [replace(v, points=v.points @ r.T + t) for v, (r, t) in zip(views, motions, strict=True)]
    return out, motions


def test_a_rigid_fit_recovers_a_rotation_and_translation():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(50, 3))
    rotation, translation = Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3)
    motion = rigid_fit(points, points @ rotation.T + translation)
    np.testing.assert_allclose(motion.rotation, rotation, atol=1e-9)
    np.testing.assert_allclose(motion.translation, translation, atol=1e-9)


def test_views_in_their_own_frames_come_back_where_they_were():
    views, places = three_views()
    sent, motions = moved(views, seed=2)
    back = aligned_views(sent, places)
    assert back is not None
    largest = int(np.argmax([view.mass.sum() for view in views]))
    rotation, translation = motions[largest]
    for original, aligned in zip(views, back, strict=True):  # in the largest view's frame
        expected = original.points @ rotation.T + translation
        assert np.sqrt(np.mean(np.sum((aligned.points - expected) ** 2, axis=1))) < 1e-3


def test_the_aligned_union_is_the_registered_union():
    views, places = three_views()
    sent, _ = moved(views, seed=4)
    # within what a rotation alone moves robust-laplacian's point-cloud Laplacian: a few tenths of a per cent
    union = aligned_union(sent, places, K, max_left_share=0.0)  # every view joined
    assert union is not None and union.joined == [0, 1, 2]
    np.testing.assert_allclose(union.eigenvalues, fused_spectrum(views, K), rtol=5e-3)


def test_views_of_two_poses_are_not_aligned():
    """The right view bent about the y axis (the surface in another pose): its overlap with the
    others cannot be brought onto theirs by any rigid motion."""
    views, places = bent_third_view()  # bent from where it starts: rigid there, bent beyond
    sent, _ = moved(views, seed=5)
    assert aligned_views(sent, places) is None


def bent_third_view() -> tuple[list[View], list[np.ndarray]]:
    """The three views, the right one bent about the y axis (the surface in another pose)."""
    views, places = three_views()
    right = views[2]
    x, z = right.points[:, 0], right.points[:, 2]
    angle = 1.2 * np.clip(x - 0.3, 0, None)
    bent = np.column_stack([0.3 + (x - 0.3) * np.cos(angle) - z * np.sin(angle), right.points[:, 1], z])
    bent[:, 2] = (x - 0.3) * np.sin(angle) + z * np.cos(angle)
    return [*views[:2], replace(right, points=bent)], places


def test_the_views_that_come_together_are_fused_where_few_are_left_out():
    """The bent view is left out: within the share of the area allowed the other two are fused
    (their registered union) and named; with none allowed, nothing is answered."""
    views, places = bent_third_view()
    sent, _ = moved(views, seed=5)
    share = views[2].mass.sum() / sum(view.mass.sum() for view in views)
    union = aligned_union(sent, places, K, max_left_share=share + 0.01)
    assert union is not None and union.joined == [0, 1]
    np.testing.assert_allclose(union.eigenvalues, fused_spectrum(views[:2], K), rtol=5e-3)
    assert aligned_union(sent, places, K, max_left_share=share - 0.01) is None
    assert aligned_union(sent, places, K, max_left_share=0.0) is None


def test_views_that_share_nothing_are_not_aligned():
    """Two views placed on one stretch of the template but far apart in shape (a place error the
    size of the overlap): the fit slides off, and nothing is answered rather than a NaN."""
    views, places = three_views()
    far = replace(views[2], points=views[2].points * 3.0)
    sent, _ = moved([views[0], far], seed=6)
    assert aligned_views(sent, [places[0], places[0][: len(far.points)]]) is None


def scrambled(places: list[np.ndarray], seed: int) -> list[np.ndarray]:
    """Each view's places shuffled among its points: places no fit can bring together."""
    rng = np.random.default_rng(seed)
    return [place[rng.permutation(len(place))] for place in places]


def test_views_sent_in_one_frame_are_joined_as_sent_where_their_places_cannot_join_them():
    """A front-end that tracks its camera but does not say so: the views already lie on one
    another, and where their places are too far off to give the motion (a child's, a close-up's),
    they are joined exactly where they were sent."""
    views, places = three_views()
    wrong = scrambled(places, seed=7)
    back = aligned_views(views, wrong)
    assert back is not None
    for original, joined in zip(views, back, strict=True):
        np.testing.assert_allclose(joined.points, original.points, atol=1e-9)
