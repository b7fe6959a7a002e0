"""The boundary check against the fitted body: a boundary point deep inside what the views saw
is freed, one where they stop is kept, and nothing is freed where no body fits."""

from functools import partial

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import shortest_path

from app.sessions.fused import FusedCloud, View, fused_cloud, fused_spectrum, view_of_part
from app.sessions.seen import DEPTH, SeenTemplate, _eroded, deep_inside

FALSE_FLAGS = 12  # a cluster of boundary points flagged where the view goes on all around them


@pytest.fixture(scope="module")
def seen(models) -> SeenTemplate:
    return SeenTemplate.of(models.body, models.template)


@pytest.fixture(scope="module")
def headless(sample_parts) -> tuple[View, np.ndarray]:
    """The template without head and neck as an upload is solved, and its placed points."""
    name, solved, placed = sample_parts[0]
    assert name == "no_head_neck.ply"
    return view_of_part(solved.part), placed.placement.position


def test_a_false_boundary_inside_the_seen_body_is_freed_and_the_cut_kept(seen, headless):
    view, places = headless
    cloud = fused_cloud([view])
    cut = cloud.boundary.copy()
    assert cut.sum() > 20  # where the neck was cut off
    belly = np.argmin(np.linalg.norm(cloud.points - cloud.points.mean(axis=0), axis=1))
    false = np.zeros_like(cut)
    false[np.argsort(np.linalg.norm(cloud.points - cloud.points[belly], axis=1))[:FALSE_FLAGS]] = True
    assert not (false & cut).any()
    flagged = FusedCloud(cloud.points, cut | false, cloud.capped)
    inside = deep_inside(seen, [view], [places], flagged)
    assert inside[false].all()
    assert not inside[cut].any()
    freed = flagged.freed(inside)
    np.testing.assert_array_equal(freed.boundary, cut)


def test_nothing_is_freed_where_too_little_was_seen_for_a_body(seen, headless):
    view, places = headless
    few = np.argsort(np.linalg.norm(view.points - view.points[0], axis=1))[:150]
    small = View(view.points[few], view.mass[few], np.zeros(len(few), bool), np.empty((0, 2), np.int64))
    flags = np.ones(len(few), bool)
    inside = deep_inside(seen, [small], [places[few]], FusedCloud(small.points, flags, 0))
    assert not inside.any()


def test_eroding_keeps_the_vertices_depth_rings_from_the_outside(seen):
    upper = seen.rest[:, 1] > np.median(seen.rest[:, 1])
    kept = _eroded(seen, upper, DEPTH)
    count = len(upper)
    outside = sp.csr_matrix(
        (np.ones((~upper).sum()), (np.zeros((~upper).sum(), int), np.flatnonzero(~upper))), (1, count)
    )
    joined = sp.bmat([[seen.graph, outside.T], [outside, None]]).tocsr()  # one node beside every vertex outside
    rings = shortest_path(joined, unweighted=True, indices=count)[:count] - 1
    np.testing.assert_array_equal(kept, upper & (rings > DEPTH))


def test_either_order_of_the_views_gives_one_union(seen, sample_parts, models):
    views = [view_of_part(solved.part) for _, solved, _ in sample_parts]
    places = [placed.placement.position for _, _, placed in sample_parts]
    rule = partial(deep_inside, seen)
    forward = fused_spectrum(views, models.k, places, rule)
    backward = fused_spectrum(views[::-1], models.k, places[::-1], rule)
    np.testing.assert_array_equal(forward, backward)
