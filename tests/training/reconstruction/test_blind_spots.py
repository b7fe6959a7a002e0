"""Scans of a body (blind spots, partial unions): surfaces the decoder's router must see as having a boundary."""

import numpy as np
import pytest

from app.contract import BOUNDARY_RATIO
from app.core.config import Settings
from app.geometry.topology import face_areas
from app.inference.template import Template
from training.data.spectra import MESH, task_spectrum
from training.reconstruction.blind_spots import blind_spot_mask
from training.reconstruction.unions import SCAN_KINDS, scan_spectra


@pytest.fixture(scope="module")
def template() -> Template:
    return Template.load(Settings().models_dir)


def test_a_blind_spot_scan_hides_a_little_of_the_body_and_never_nothing(template):
    area = np.zeros(len(template.vertices))
    np.add.at(area, template.faces.ravel(), np.repeat(face_areas(template.vertices, template.faces) / 3, 3))
    rng = np.random.default_rng(0)
    hidden = np.array([area[~blind_spot_mask(template.vertices, rng)].sum() / area.sum() for _ in range(200)])
    assert (hidden > 0).all()
    assert hidden.max() < 0.10  # small holes, not parts: the scan is of the whole body
    first, again = (blind_spot_mask(template.vertices, np.random.default_rng(7)) for _ in range(2))
    np.testing.assert_array_equal(first, again)  # a seed gives the same scans: the rows are reproducible


def test_every_scan_of_a_body_is_a_boundary_to_the_router_and_no_larger_than_the_body(template, tmp_path):
    """Dirichlet λ₁ is 0 on a closed surface and positive on one with a hole, and an eigenvalue
    can only rise as the domain shrinks: the closed template on one side of the decoder's
    threshold, each of its scans (the bodies build's, blind spots and partial unions) on the
    other, and every scan's eigenvalues at or above the body's."""
    closed = task_spectrum(template.vertices, template.faces, np.ones(len(template.vertices), bool), MESH, 20)
    assert closed[0] <= BOUNDARY_RATIO * closed[1]
    rest = tmp_path / "rest.npy"
    np.save(rest, template.vertices[None].astype(np.float32))
    scans = scan_spectra(str(Settings().models_dir), str(rest), 0, 20, 0)
    assert scans.shape == (len(SCAN_KINDS), 20) and np.isfinite(scans).all()
    assert (scans[:, 0] > BOUNDARY_RATIO * scans[:, 1]).all()
    assert (scans >= closed - 1e-6 * closed.max()).all()
