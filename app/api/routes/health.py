"""Liveness and readiness probes."""

from fastapi import APIRouter, Request

from app.api.problems import ProblemError, problem_responses

router = APIRouter(tags=["health"])


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """The process is up and serving HTTP."""
    return {"status": "ok"}


@router.get("/readyz", responses=problem_responses(503, slugs={"not-ready"}))
async def readyz(request: Request) -> dict[str, str]:
    """Models loaded and verified, database reachable; 503 with the reasons otherwise."""
    if not getattr(request.app.state, "ready", False):
        raise ProblemError(503, "not-ready", "Not ready", "the service is starting or stopping")
    problems = await request.app.state.resources.problems()
    if problems:
        raise ProblemError(503, "not-ready", "Not ready", "; ".join(problems))
    return {"status": "ready"}
