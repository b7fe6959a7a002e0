"""A session's view and union as database columns, one definition for SQLite and PostgreSQL.

A view is kept whole, so that the session's union can always be read again from its views: its
spectrum (float64), its geometry (an NPZ of plain arrays, read back without pickle: points and
areas as float32, a tenth of a micrometre at a body's size, the boundary and its edges), its
template cover as a region token and its place's confidence and area.
"""

import io
import json
from dataclasses import dataclass

import numpy as np

from app.inference.cover import cover_of_text, cover_text
from app.inference.models import UnionEstimate
from app.sessions.chain import Located
from app.sessions.fused import View
from app.sessions.session import SessionUnion, SessionView

VIEW_COLUMNS = ("source", "eigenvalues", "geometry", "region", "confidence", "area", "warnings")


class SessionNotFound(LookupError):
    """No such session: never made, ended, or expired."""


class SessionFull(Exception):
    """The session holds as many views as the service keeps."""

    @classmethod
    def holding(cls, views: int) -> "SessionFull":
        return cls(f"the session holds {views} views, as many as this service keeps")


@dataclass(frozen=True)
class SessionMeta:
    """What a session was made with, and when (seconds since the epoch)."""

    id: str
    registered: bool
    units: str
    scale: float | None
    created_at: float
    touched_at: float
    views: int


def view_row(view: SessionView) -> tuple:
    """A view's columns, in :data:`VIEW_COLUMNS` order."""
    buffer = io.BytesIO()
    geometry = view.geometry
    faces = {} if geometry.faces is None else {"faces": geometry.faces.astype(np.int32)}
    np.savez(
        buffer,
        points=geometry.points.astype(np.float32),
        mass=geometry.mass.astype(np.float32),
        boundary=geometry.boundary,
        edges=geometry.edges.astype(np.int32),
        places=view.places.astype(np.float32),
        trusted=np.bool_(view.located.trusted),
        **faces,
    )
    return (
        view.source,
        np.asarray(view.eigenvalues, dtype=np.float64).tobytes(),
        buffer.getvalue(),
        cover_text(view.located.cover),
        view.located.confidence,
        view.located.area,
        json.dumps(list(view.warnings)),
    )


def view_of_row(row: tuple, template_vertices: int) -> SessionView:
    """A view read back from its columns (:func:`view_row`)."""
    source, eigenvalues, geometry, region, confidence, area, warnings = row
    with np.load(io.BytesIO(bytes(geometry)), allow_pickle=False) as arrays:
        view = View(
            arrays["points"].astype(np.float64),
            arrays["mass"].astype(np.float64),
            arrays["boundary"].astype(bool),
            arrays["edges"].astype(np.int64),
            arrays["faces"].astype(np.int64) if "faces" in arrays else None,  # a point cloud's view has none
        )
        places = arrays["places"].astype(np.float64)
        trusted = bool(arrays["trusted"]) if "trusted" in arrays else True
    cover = cover_of_text(region, template_vertices, "stored view")
    located = Located(cover, float(confidence), float(area), trusted)
    values = np.frombuffer(bytes(eigenvalues), dtype=np.float64).copy()
    return SessionView(source, values, view, places, located, tuple(json.loads(warnings)))


def union_text(union: SessionUnion) -> str:
    """A session's union as the text its row caches it by."""
    return json.dumps(
        {
            "eigenvalues": union.estimate.eigenvalues.tolist(),
            "sigma": union.estimate.sigma.tolist(),
            "nested": list(union.estimate.nested),
            "union_by": union.union_by,
            "overlaps": union.overlaps,
            "overlaps_told": union.overlaps_told,
        }
    )


def union_of_text(text: str) -> SessionUnion:
    """A cached union read back (:func:`union_text`)."""
    content = json.loads(text)
    estimate = UnionEstimate(
        np.array(content["eigenvalues"], dtype=np.float64),
        np.array(content["sigma"], dtype=np.float64),
        tuple(content["nested"]),
    )
    return SessionUnion(estimate, content["union_by"], content["overlaps"], content["overlaps_told"])
