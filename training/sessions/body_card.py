"""The model card's bodies section, generated from ``models/bodies.json``: the body fitted to a
scanning session's views and its measurements, on Test C's people, beside the mean body, and the
goals."""

from training.card.tables import percent

BEGIN, END = "<!-- bodies:begin -->", "<!-- bodies:end -->"
GOAL_BODY_MM = 15.0  # the body from a 5-view session, mean vertex error
GOAL_GIRTH_MM, GOAL_STATURE_MM = 15.0, 10.0  # measurements from a 5-view session, mean absolute error
GOAL_WHOLE_GIRTH_MM, GOAL_WHOLE_HEIGHT_MM = 9.0, 4.0  # a session covering the body: ISO 20685-1's allowances
GOAL_IDENTITY = 0.97  # the person scanned answered first from a 5-view session
GIRTHS = ("chest_girth", "waist_girth", "hip_girth")
HEIGHTS = ("stature", "crotch_height")
SHORT = {
    "stature": "stature",
    "chest_girth": "chest",
    "waist_girth": "waist",
    "hip_girth": "hip",
    "crotch_height": "crotch h.",
    "arm_length": "arm",
    "shoulder_breadth": "shoulder b.",
}


def _worst(row: dict, names: tuple[str, ...]) -> float:
    """The largest mean absolute error (mm) among ``names`` that were measured."""
    errors = [row["measurements"][name]["mae_mm"] for name in names if row["measurements"][name]["mae_mm"] is not None]
    return max(errors) if errors else float("inf")


def goals(metrics: dict) -> dict[str, bool]:
    """Each goal of the fitted body and its measurements, met or not."""
    rows = metrics["evaluation"]
    five, whole = rows["5/registered"], rows["24/registered"]
    return {
        f"body from 5 views ≤ {GOAL_BODY_MM:.0f} mm": five["vertex_mm"] <= GOAL_BODY_MM,
        f"girths from 5 views ≤ {GOAL_GIRTH_MM:.0f} mm": _worst(five, GIRTHS) <= GOAL_GIRTH_MM,
        f"stature from 5 views ≤ {GOAL_STATURE_MM:.0f} mm": _worst(five, ("stature",)) <= GOAL_STATURE_MM,
        f"24 views: girths ≤ {GOAL_WHOLE_GIRTH_MM:.0f} mm, heights ≤ {GOAL_WHOLE_HEIGHT_MM:.0f} mm": (
            _worst(whole, GIRTHS) <= GOAL_WHOLE_GIRTH_MM and _worst(whole, HEIGHTS) <= GOAL_WHOLE_HEIGHT_MM
        ),
        f"identity from 5 views ≥ {100 * GOAL_IDENTITY:.0f} %": five["identity"]["top1"] >= GOAL_IDENTITY,
    }


def _per_band(metrics: dict, key: str) -> str:
    """A calibration factor per band of view counts, as ``≤ 5: 3.1, …``."""
    return ", ".join(f"≤ {band}: {scale:.2f}" for band, scale in zip(metrics["bands"], metrics[key], strict=True))


def _cell(measure: dict) -> str:
    if measure["mae_mm"] is None:
        return "—"
    return f"{measure['mae_mm']:.1f} ({measure['mean_body_mae_mm']:.0f})"


def render(metrics: dict, command: str) -> str:
    """The card's bodies table and its goals."""
    rows = metrics["evaluation"]
    names = list(next(iter(rows.values()))["measurements"])
    lines = [
        BEGIN,
        f"Produced by `{command}`.",
        "",
        f"The body `GET /v1/sessions/{{id}}/body` fits to a session's views, on {metrics['test_c_people']} of Test C's "
        "people (the sessions above, as cut and re-meshed, pooled; in their own frames: those whose views came "
        "together, the others answer 409): mean vertex error against the person at rest (mm, after a rigid "
        "alignment), the mean body's beside it; each measurement's mean absolute error against the same "
        "measurement on the true body, mm (the mean body's in brackets; — where the views did not support it); how "
        f"often the 90 % intervals held (σ × {_per_band(metrics, 'sigma_scale')}, spread × "
        f"{_per_band(metrics, 'spread_scale')} by view count, fitted on other people, men, women and children; "
        "a fit's σ and intervals widened in proportion where it leaves its points farther from the body than "
        f"the calibration fits' median gap, {1e3 * metrics['fit_residual_m']:.1f} mm). "
        "Identity (`GET /v1/sessions/{id}/identity`): the stored people ranked by the Mahalanobis distance of their "
        "shape coefficients at rest from the fitted body's, under the fit's posterior, in the seed database, where "
        "these people are stored in ten poses of their own (none the session's): the person scanned answered first "
        f"/ among the first five, the first answer's mean confidence (τ = {metrics['shape_identity_scale']:.2f}); "
        "first by the rankings before, the fitted body's closed spectrum and the session's union decoded into a "
        "body; first by the person's true body's spectrum at rest (the most a spectrum can do). People stored as "
        "scans (`POST /v1/shapes`) are ranked less surely, most of all scans in a pose far from rest "
        "(`python -m benchmarks.identity_from_stored_scans`).",
        "",
        "| views | fitted | body mm (p95) | mean body | " + " | ".join(SHORT[n] for n in names) + " | held: vertices / "
        "measurements | identity: first / five / confidence | not stored: warned / falsely | fitted body's spectrum | "
        "union decoded | true body |",
        "|---" * (10 + len(names)) + "|",
    ]
    for key, row in rows.items():
        measured = [row["measurements"][n] for n in names if row["measurements"][n]["held"] is not None]
        held = sum(m["held"] * m["measured"] for m in measured) / max(sum(m["measured"] for m in measured), 1)
        identity = row["identity"]
        today = "—" if identity["today_top1"] is None else percent(identity["today_top1"])
        lines.append(
            f"| {key} | {row['fitted']} of {row['sessions']} | {row['vertex_mm']:.1f} ({row['vertex_p95_mm']:.0f}) | "
            f"{row['mean_body_mm']:.0f} | " + " | ".join(_cell(row["measurements"][n]) for n in names) + " | "
            f"{percent(row['vertex_held'])} / {percent(held)} | {percent(identity['top1'])} / "
            f"{percent(identity['top5'])} / {percent(identity['confidence'])} | "
            f"{percent(identity['not_stored_warned'])} / {percent(identity['stored_warned'])} | "
            f"{percent(identity['spectrum_top1'])} | {today} | "
            f"{percent(identity['ceiling_top1'])} |"
        )
    verdicts = "; ".join(f"{goal}: {'met' if met else '**not met**'}" for goal, met in goals(metrics).items())
    lines += ["", f"Goals: {verdicts}.", END]
    return "\n".join(lines)
