"""A typed Python client of the service (httpx): every endpoint, answers as the service's own
response models, every error as one exception carrying the problem body.

The response classes are the ones the routes declare (``app.api.routes``) and the spectrum
report is the pipeline's dataclass, so the client cannot drift from what the service sends.

    with Client("http://127.0.0.1:8000") as client:
        part = client.spectrum("no_head_neck.ply")
        union = client.union(files=["no_left_forearm_hand.ply"], spectra=[part.eigenvalues])

A scanner's registered views sent one by one keep their footprint tokens, and have each new
view's overlap measured against the union so far, which the union routes are then told:

        views = [client.spectrum(scan, footprint=True) for scan in scans]
        measured = client.overlap([view.footprint for view in views])
        union = client.union(spectra=[view.eigenvalues for view in views], overlap=measured.overlaps)

A front-end that posts views as it scans keeps a session instead: each view answers the union of
all the views so far, what they cover and what to scan next:

        session = client.new_session(registered=True)
        for scan in scans:
            state = client.add_view(session.id, scan)
            print(state.union_by, state.eigenvalues[:3], state.least_covered)
"""

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Literal, Self

import httpx

from app.api.problems import PROBLEM_MEDIA_TYPE, Problem
from app.api.responses import UnionResponse
from app.api.routes.correspondence import CorrespondenceResponse, PlacesKind
from app.api.routes.localize import LocalizeResponse
from app.api.routes.models import ModelsResponse
from app.api.routes.overlap import OverlapResponse
from app.api.routes.reconstruct import ReconstructResponse
from app.api.routes.retrieve import RetrieveResponse
from app.api.routes.session_person import BodyAnswer
from app.api.routes.sessions import SessionOptions, SessionResponse
from app.api.routes.shapes import ShapeOut, ShapePage
from app.api.routes.spectrum import FootprintedReport
from app.geometry.pipeline import SpectrumReport
from app.geometry.spectrum import DEFAULT_K

Scan = str | os.PathLike[str] | tuple[str, bytes]  # a file path, or (file name, its bytes)
Units = Literal["m", "cm", "mm"]
DEFAULT_URL = "http://127.0.0.1:8000"


class ServiceProblem(Exception):
    """Any non-2xx answer, with its problem body (``type`` is what to branch on)."""

    def __init__(self, problem: Problem) -> None:
        super().__init__(f"{problem.status} {problem.type}: {problem.detail}")
        self.problem = problem

    @property
    def status(self) -> int:
        return self.problem.status

    @property
    def type(self) -> str:
        return self.problem.type


class Client:
    """The service at ``base_url``; ``api_key`` is needed for writes to ``/v1/shapes``.

    ``http`` may be an ``httpx.Client`` of the caller's (its base URL is used as it is): a
    FastAPI ``TestClient`` makes the client run against an app in the same process.
    """

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        *,
        api_key: str | None = None,
        timeout: float = 180.0,
        http: httpx.Client | None = None,
    ) -> None:
        self._owned = http is None
        self._http = http or httpx.Client(base_url=base_url, timeout=timeout)
        self._api_key = api_key

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection pool, unless it was the caller's."""
        if self._owned:
            self._http.close()

    def spectrum(
        self,
        scan: Scan,
        *,
        k: int = DEFAULT_K,
        units: Units = "m",
        scale: float | None = None,
        closed: bool = False,
        boundary: Sequence[int] | None = None,
        footprint: bool = False,
        cap_holes: bool = False,
    ) -> SpectrumReport | FootprintedReport:
        """The first ``k`` eigenvalues of one scan (Dirichlet where it has a boundary), in 1/m²;
        with ``footprint`` also its footprint token, for :meth:`overlap`; with ``cap_holes`` a
        whole-body mesh's holes capped first (its closed spectrum)."""
        params = _params(
            k=k, units=units, scale=scale, closed=closed, footprint=footprint or None, cap_holes=cap_holes or None
        )
        data = {"boundary": json.dumps(list(boundary))} if boundary is not None else None
        body = self._post("/v1/spectrum", params, files=[("file", _part(scan))], data=data)
        return FootprintedReport(**body) if footprint else SpectrumReport(**body)

    def correspondence(
        self,
        scan: Scan,
        *,
        units: Units = "m",
        scale: float | None = None,
        closed: bool = False,
        boundary: Sequence[int] | None = None,
        places: PlacesKind = "network",
    ) -> CorrespondenceResponse:
        """Each vertex of one scan placed on the template's rest pose, with its confidence, and the
        template region it covers (``region.token`` to send back in ``regions`` beside its spectrum);
        ``places="relaxed"``: the places relaxed toward the scan's own edge lengths (closer to the
        truth, where a client reads the places themselves)."""
        params = _params(units=units, scale=scale, closed=closed, places=places)
        data = {"boundary": json.dumps(list(boundary))} if boundary is not None else None
        return CorrespondenceResponse(
            **self._post("/v1/correspondence", params, files=[("file", _part(scan))], data=data)
        )

    def overlap(self, footprints: Sequence[str]) -> OverlapResponse:
        """Each union step's overlap and boundary share of registered views, from their footprint
        tokens (the union so far's ``union_footprint`` may stand for all the earlier ones)."""
        field = [("footprints", (None, json.dumps(list(footprints))))]  # multipart: 1 MiB a field
        return OverlapResponse(**self._post("/v1/overlap", {}, files=field, data=None))

    def union(
        self,
        files: Sequence[Scan] = (),
        spectra: Sequence[Sequence[float]] = (),
        *,
        units: Units = "m",
        scale: float | None = None,
        overlap: Sequence[float] | None = None,
        boundary: Sequence[float] | None = None,
        measure_overlap: bool = False,
        regions: Sequence[str] | None = None,
    ) -> UnionResponse:
        """The union's spectrum and its 90 % interval; files first, then spectra, folded left to right;
        ``overlap`` (one share per union step) where known, with ``boundary`` (each step's boundary share)
        where that is known too, or ``measure_overlap`` for registered uploads; ``regions``: each spectrum's
        region token, where it lies on the template (uploads are placed by the service)."""
        params = _union_params(units, scale, overlap, boundary, measure_overlap)
        return UnionResponse(**self._operands("/v1/union", files, spectra, params, regions))

    def localize(
        self,
        files: Sequence[Scan] = (),
        spectra: Sequence[Sequence[float]] = (),
        *,
        units: Units = "m",
        scale: float | None = None,
        overlap: Sequence[float] | None = None,
        boundary: Sequence[float] | None = None,
        measure_overlap: bool = False,
        regions: Sequence[str] | None = None,
    ) -> LocalizeResponse:
        """The union, its region on the template body and the covered share of each body part."""
        params = _union_params(units, scale, overlap, boundary, measure_overlap)
        return LocalizeResponse(**self._operands("/v1/localize", files, spectra, params, regions))

    def reconstruct(
        self,
        files: Sequence[Scan] = (),
        spectra: Sequence[Sequence[float]] = (),
        *,
        units: Units = "m",
        scale: float | None = None,
        overlap: Sequence[float] | None = None,
        boundary: Sequence[float] | None = None,
        measure_overlap: bool = False,
        regions: Sequence[str] | None = None,
        cap_holes: bool = False,
    ) -> ReconstructResponse:
        """The person's body rebuilt from the union's spectrum (rest pose, template topology), with
        its height, area and its own spectrum as the check; ``cap_holes``: one whole-body mesh,
        its holes capped first."""
        params = _union_params(units, scale, overlap, boundary, measure_overlap) | _params(cap_holes=cap_holes or None)
        return ReconstructResponse(**self._operands("/v1/reconstruct", files, spectra, params, regions))

    def retrieve(
        self,
        files: Sequence[Scan] = (),
        spectra: Sequence[Sequence[float]] = (),
        *,
        top: int = 10,
        rebuild: bool = True,
        profile: bool = True,
        units: Units = "m",
        scale: float | None = None,
        overlap: Sequence[float] | None = None,
        boundary: Sequence[float] | None = None,
        measure_overlap: bool = False,
        regions: Sequence[str] | None = None,
        cap_holes: bool = False,
    ) -> RetrieveResponse:
        """The stored complete shapes nearest to the union of the operands; an open surface (a scan with
        holes) is ranked through the body the shape decoder rebuilds from it unless ``rebuild`` is False;
        two operands whose overlap is not told, by their share profile unless ``profile`` is False;
        ``cap_holes``: one whole-body mesh, its holes capped first (ranked as the closed surface)."""
        params = {"top": top, "rebuild": rebuild, "profile": profile}
        params |= _union_params(units, scale, overlap, boundary, measure_overlap)
        params |= _params(cap_holes=cap_holes or None)
        return RetrieveResponse(**self._operands("/v1/retrieve", files, spectra, params, regions))

    def models(self) -> ModelsResponse:
        """What the service has loaded: model version, k, template, database."""
        return ModelsResponse(**self._answer(self._http.get("/v1/models")))

    def shapes(self, *, offset: int = 0, limit: int = 50) -> ShapePage:
        """One page of the stored complete shapes, oldest first."""
        return ShapePage(**self._answer(self._http.get("/v1/shapes", params={"offset": offset, "limit": limit})))

    def add_shape(
        self, scan: Scan, label: str, *, units: Units = "m", scale: float | None = None, cap_holes: bool = False
    ) -> ShapeOut:
        """Store a complete (closed) shape's spectrum under an identity label (needs the API key);
        ``cap_holes``: a whole-body scan whose blind spots are capped first."""
        params = _params(units=units, scale=scale, cap_holes=cap_holes or None)
        body = self._post("/v1/shapes", params, files=[("file", _part(scan))], data={"label": label})
        return ShapeOut(**body)

    def delete_shape(self, shape_id: str) -> None:
        """Remove a stored shape (needs the API key)."""
        self._answer(self._http.delete(f"/v1/shapes/{shape_id}", headers=self._key_header()))

    def new_session(
        self, *, registered: bool = False, units: Units = "m", scale: float | None = None
    ) -> SessionResponse:
        """Start a scanning session; ``registered``: its views share one frame and pose (a tracked
        scanner's), so their union is solved once on the views themselves."""
        options = SessionOptions(registered=registered, units=units, scale=scale)
        return SessionResponse(**self._answer(self._http.post("/v1/sessions", json=options.model_dump())))

    def add_view(self, session_id: str, scan: Scan, *, boundary: Sequence[int] | None = None) -> SessionResponse:
        """Add one view to a session: the session answered with it (the union of all its views,
        coverage, the body parts least covered)."""
        data = {"boundary": json.dumps(list(boundary))} if boundary is not None else None
        body = self._post(f"/v1/sessions/{session_id}/views", {}, files=[("file", _part(scan))], data=data)
        return SessionResponse(**body)

    def session(self, session_id: str) -> SessionResponse:
        """A session as it stands: its views, their union and coverage."""
        return SessionResponse(**self._answer(self._http.get(f"/v1/sessions/{session_id}")))

    def session_body(self, session_id: str) -> BodyAnswer:
        """The body fitted to a session's views, at rest, and the measurements they support."""
        return BodyAnswer(**self._answer(self._http.get(f"/v1/sessions/{session_id}/body")))

    def end_session(self, session_id: str) -> None:
        """End a session: it and its views are deleted."""
        self._answer(self._http.delete(f"/v1/sessions/{session_id}"))

    def _operands(
        self,
        path: str,
        files: Sequence[Scan],
        spectra: Sequence[Sequence[float]],
        params: dict,
        regions: Sequence[str] | None = None,
    ) -> dict:
        """Files and spectra as the union routes take them, and the spectra's region tokens
        (``regions``, one per spectrum: where each lies on the template, as :meth:`correspondence`
        or :meth:`localize` answered it)."""
        data = {"spectra": json.dumps([[float(v) for v in s] for s in spectra])} if spectra else {}
        if regions is not None:
            data["regions"] = json.dumps(list(regions))
        return self._post(path, params, files=[("files", _part(scan)) for scan in files] or None, data=data or None)

    def _post(self, path: str, params: dict, *, files: list | None, data: dict | None) -> dict:
        response = self._http.post(path, params=params, files=files, data=data, headers=self._key_header())
        return self._answer(response)

    def _key_header(self) -> dict[str, str]:
        return {"X-API-Key": self._api_key} if self._api_key else {}

    @staticmethod
    def _answer(response: httpx.Response) -> dict:
        """The JSON body of a 2xx (``{}`` for 204), or :class:`ServiceProblem`."""
        if response.is_success:
            return response.json() if response.content else {}
        if response.headers.get("content-type", "").startswith(PROBLEM_MEDIA_TYPE):
            raise ServiceProblem(Problem(**response.json()))
        # Not the service's own answer (a proxy's HTML page, say): the same exception, built here.
        raise ServiceProblem(
            Problem(type="about:blank", title=response.reason_phrase, status=response.status_code, detail=response.text)
        )


def _part(scan: Scan) -> tuple[str, bytes, str]:
    """A multipart file part; the service reads the type from the file name's extension."""
    if isinstance(scan, tuple):
        name, data = scan
    else:
        name, data = Path(scan).name, Path(scan).read_bytes()
    return name, data, "application/octet-stream"


def _params(**values: object) -> dict:
    """Query parameters without the ``None`` ones (the service's defaults apply)."""
    return {key: value for key, value in values.items() if value is not None}


def _union_params(
    units: Units, scale: float | None, overlap: Sequence[float] | None, boundary: Sequence[float] | None, measure: bool
) -> dict:
    """The union-based routes' query parameters: units, and the overlap (and boundary share) told
    or to be measured."""
    told, edge = (",".join(repr(float(x)) for x in v) if v is not None else None for v in (overlap, boundary))
    return _params(units=units, scale=scale, overlap=told, boundary=edge, measure_overlap=measure or None)
