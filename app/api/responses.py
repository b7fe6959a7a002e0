"""What several routes answer alike, in one place they import rather than each other: the union's
answer (``/v1/localize`` and ``/v1/reconstruct`` extend it) and the problems every union-based
route can answer, the models' version field, and the media type of ``.npz`` answers."""

from dataclasses import asdict
from typing import Annotated, Any, Literal

from fastapi import Query
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from app.api.problems import MODEL_SLUGS, UPLOAD_PROBLEMS, UPLOAD_SLUGS, problem_responses
from app.retrieval.store import Match
from app.sessions.identity import Candidate, ahead_warning, ranked_people

NPZ_MEDIA_TYPE = "application/x-npz"  # numpy's zip of NPY arrays; np.load reads it
# What the union-based routes can answer: an upload's problems, and the models'.
UNION_PROBLEMS = problem_responses(*UPLOAD_PROBLEMS, slugs=UPLOAD_SLUGS | MODEL_SLUGS)
MODEL_VERSION_FIELD = Field(description="Content hash of the ONNX models: replicas agree iff they serve the same.")
DetailQuery = Annotated[
    Literal["full", "coverage"],
    Query(
        description="coverage: the answer without its per-vertex arrays (those fields absent, not empty): a "
        "front-end that shows what is covered and what to scan next reads a few hundred bytes instead of a few "
        "hundred kilobytes."
    ),
]


def shaped(answer: BaseModel, detail: str, per_vertex: dict[str, Any]) -> BaseModel | JSONResponse:
    """``answer`` whole, or with ``detail`` coverage without its ``per_vertex`` fields (a pydantic
    exclude: field name → True, or a nested one's)."""
    if detail == "full":
        return answer
    return JSONResponse(answer.model_dump(mode="json", exclude=per_vertex))


class OperandSpectrum(BaseModel):
    source: str = Field(description="files[i] <name> or spectra[i].")
    eigenvalues: list[float] = Field(description="The operand's own spectrum, 1/m²: send it back as a spectrum.")


class UnionInterval(BaseModel):
    """A union's spectrum and its 90 % interval, as every answer that holds a union gives them."""

    eigenvalues: list[float] = Field(description="Spectrum of the union, 1/m², non-decreasing.")
    sigma: list[float] = Field(
        description="Per-eigenvalue standard deviation, 1/m², calibrated on held-out unions (0 for one operand)."
    )
    lower: list[float] = Field(description="Lower end of the 90 % interval.")
    upper: list[float] = Field(description="Upper end of the 90 % interval.")


class UnionResponse(UnionInterval):
    operands: list[OperandSpectrum] = Field(description="Each operand's own spectrum, for caching.")
    union_by: Literal["operand", "fused", "aligned", "aligned-and-chained", "learned-chain"] = Field(
        description="What made the union: operand (one operand, returned as is, σ 0); where every operand is an "
        "uploaded file, the uploads themselves as a scanning session reads its views: fused (declared in one "
        "frame and pose with measure_overlap=true: fused and solved once, meshes glued through their own "
        "triangles), aligned (brought into one frame through their places on the template, or joined where "
        "they were sent where they already lie on one another, then fused) or aligned-and-chained (a few that did not "
        "align chained onto the others' union); otherwise learned-chain (the learned operator folded over the "
        "operands' spectra, left to right: spectra sent without geometry, or told overlaps)."
    )
    model_version: str = MODEL_VERSION_FIELD
    solve_ms: float = Field(description="Eigen-solves of the uploaded files.")
    inference_ms: float = Field(
        description="The union's own time: the learned operator, or the uploads fused and solved."
    )
    overlaps: list[float] = Field(
        default_factory=list,
        description="Each union step's overlap (share of the smaller operand inside the other), as told in "
        "overlap, measured with measure_overlap or read from the operands' places (up to the first operand whose "
        "places are doubted); empty when none.",
    )
    boundaries: list[float] = Field(
        default_factory=list,
        description="Each union step's boundary share (how much of the two operands' boundary length is left on "
        "the union's), as told in boundary or measured with measure_overlap by models that read it; empty when "
        "neither.",
    )
    overlaps_from: Literal["told", "footprints", "correspondence"] | None = Field(
        None,
        description="Where overlaps and boundaries came from: told by the client (overlap, boundary), measured "
        "from registered views (measure_overlap), or from the operands' places on the template (the "
        "correspondence model's, whenever every operand is an uploaded file or a spectrum sent with its region, "
        "and the client told nothing); null when none.",
    )
    overlaps_told: list[bool] = Field(
        default_factory=list,
        description="Per union step, whether the union operator was told its overlap (a client's own always is; "
        "one measured from the parts' places where the model card's validation pairs show it helps: below the "
        "graph's threshold).",
    )
    overlaps_nested: list[bool] = Field(
        default_factory=list,
        description="Per union step measured from places, whether it was told nested (overlap 1) instead of its "
        "measured overlap: every eigenvalue of one operand is at least the other's (as one part lying inside "
        "another must show) and that operand was placed with a mean confidence below the graph's threshold, too "
        "uncertain to measure how much of it lies inside.",
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="What looks wrong though it was answered: an uploaded shape's implausible area, "
        "operands more than 10× apart in size (a unit slip?), or an upload whose places on the template are too "
        "uncertain to trust its region, each naming its operand.",
    )


class PersonAnswer(BaseModel):
    label: str = Field(description="The stored person's identity label.")
    shape_id: str = Field(description="Their stored shape nearest the query (a person is stored in several poses).")
    distance: float = Field(
        description="Ranked by shape: the Mahalanobis distance of that shape's body (its person's shape coefficients) "
        "from the fitted body's, under the fit's uncertainty; otherwise the ShapeDNA distance from the spectrum "
        "ranked to that shape's."
    )
    confidence: float | None = Field(
        description="Ranked by a fitted body: a softmax of −d²/2τ² over the people ranked, τ calibrated on anny "
        "sessions (how often the first person is the one scanned: the model card's bodies section); null for "
        "rankings it was not calibrated on."
    )


def answered_people(matches: list[Match], top: int, scale: float | None) -> tuple[list[PersonAnswer], list[str]]:
    """The ``top`` people of ``matches``, one per label (:func:`app.sessions.identity.ranked_people`),
    with their confidence at ``scale`` (None: the ranking has no calibrated confidence, answered
    null), and the warning when the first is not clearly ahead."""
    return answered(ranked_people(matches, top, scale or 1.0), calibrated=scale is not None)


def answered(candidates: list[Candidate], calibrated: bool) -> tuple[list[PersonAnswer], list[str]]:
    """Ranked people as answered (their confidence null where it was not ``calibrated``), and the
    warning when the first is not clearly ahead."""
    people = [PersonAnswer(**(asdict(person) | ({} if calibrated else {"confidence": None}))) for person in candidates]
    return people, ahead_warning(people[0].confidence if people else None)
