"""A union read from the views themselves, without a server: the README's two sample parts (the
template less head and neck, less left forearm and hand) cover the whole body between them."""

from dataclasses import replace

import anyio
import numpy as np

from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.sessions.reading import views_union
from app.sessions.seen import seen_in_worker
from app.sessions.session import session_view
from app.sessions.solved import solved_union


def views_of(sample_parts):
    return [session_view(name, solved, placed, []) for name, solved, placed in sample_parts]


def test_registered_views_whose_union_closes_are_fused_into_the_closed_body(models, sample_parts):
    async def solve(views, places, registered, k, seen_with):
        return solved_union(views, places, registered, k, None if seen_with is None else seen_in_worker(seen_with))

    union = anyio.run(views_union, models, views_of(sample_parts), True, solve)
    assert union.union_by == "fused" and union.overlaps == []
    closed = mesh_spectrum(Mesh(models.template.vertices, models.template.faces), SpectrumOptions(k=models.k))
    truth = np.asarray(closed.eigenvalues)
    assert union.estimate.eigenvalues[0] < 1e-6  # closed, as the body: λ₁ = 0
    # glued from the parts' own triangles, the union is the body's mesh again
    np.testing.assert_allclose(union.estimate.eigenvalues[1:], truth[1:], rtol=1e-6)


def test_a_view_whose_place_is_doubted_is_fused_without_the_template_check(models, sample_parts):
    asked = []

    async def solve(views, places, registered, k, seen_with):
        asked.append(seen_with)
        return solved_union(views, places, registered, k, None)

    views = views_of(sample_parts)
    anyio.run(views_union, models, views, True, solve)
    doubted = [views[0], replace(views[1], located=replace(views[1].located, trusted=False))]
    anyio.run(views_union, models, doubted, True, solve)
    assert asked == [str(models.directory), None]


def test_one_view_is_no_union_of_views(models, sample_parts):
    async def solve(*args):
        raise AssertionError("one view is its own union: nothing to solve")

    assert anyio.run(views_union, models, views_of(sample_parts)[:1], True, solve) is None
