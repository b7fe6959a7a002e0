"""The model card's sessions section, generated from ``models/sessions.json``: a scanning
session's union as ``/v1/sessions`` answers it on Test C's people, beside the learned chain and
the elementwise minimum, and the goals."""

from training.card.tables import percent

BEGIN, END = "<!-- sessions:begin -->", "<!-- sessions:end -->"
GOAL_ANY, GOAL_REGISTERED, GOAL_DRIFT = 0.06, 0.03, 0.01  # every length; registered; 24 views over 3
SERVED = ("unregistered", "registered")


def lengths(metrics: dict) -> list[int]:
    """The session lengths scored, shortest first."""
    return sorted({int(key.split("/")[0]) for key in metrics["evaluation"]})


def worst(metrics: dict, method: str) -> float:
    """A reading's worst mean error over the lengths and deliveries scored."""
    return max(row[method] for row in metrics["evaluation"].values())


def goals(metrics: dict) -> dict[str, bool]:
    """Each goal of a session's union as served, met or not (every delivery counts)."""
    rows = metrics["evaluation"]
    drift = [
        rows[f"24/{variant}"][method] - rows[f"3/{variant}"][method]
        for variant in ("mesh", "remeshed")
        for method in SERVED
        if f"24/{variant}" in rows and f"3/{variant}" in rows
    ]
    registered = worst(metrics, "registered") <= GOAL_REGISTERED
    return {
        f"≤ {100 * GOAL_ANY:.0f} % at every length (unregistered)": worst(metrics, "unregistered") <= GOAL_ANY,
        f"≤ {100 * GOAL_REGISTERED:.0f} % at every length (registered)": registered,
        "24 views ≤ 3 views + 1 point": bool(drift) and max(drift) <= GOAL_DRIFT,
    }


def _bands(metrics: dict, method: str) -> str:
    return ", ".join(
        f"≤ {band['views_up_to']}: {percent(band['held_out_coverage'])}"
        for band in metrics["methods"][method]["bands"]
        if band["held_out_coverage"] is not None
    )


def render(metrics: dict, command: str) -> str:
    """The card's sessions table and its goals."""
    rows = metrics["evaluation"]
    aligned_from = [band["views_up_to"] for band in metrics["methods"]["aligned"]["bands"]]
    chosen = [band["unregistered_by"] for band in metrics["methods"]["aligned"]["bands"]]
    reading = ", ".join(f"≤ {up_to}: {by}" for up_to, by in zip(aligned_from, chosen, strict=True))
    lines = [
        BEGIN,
        f"Produced by `{command}`.",
        "",
        f"A scanning session's union as `/v1/sessions` answers it, on {metrics['test_c_people']} of Test C's people "
        "(a camera at 8 azimuths: a far view, a close-up and a re-scan each, then views from above and below, in "
        "that order; views as cut / re-meshed; truth: the union of the views' regions solved by the service); mean "
        "relative error over λ₁…λ₂₀. Registered: the views fused and solved once (a view another holds whole left "
        "out, the others glued through their own triangles), the boundary points deep inside the template region "
        "the body fitted to them saw freed. Unregistered: each view sent in "
        f"a random frame of its own, read as the calibration chose per band of views ({reading}; aligned: "
        "brought into one frame through their places and fused; where views holding at most a quarter of the area "
        "did not come together, those chained onto the others' union; the chain alone where more did not; aligned "
        "share: the sessions read so); beside them "
        "the learned chain alone and the elementwise minimum. Interval held: the served union's 90 % interval "
        f"(held out of the calibration, fused {_bands(metrics, 'fused')}; aligned {_bands(metrics, 'aligned')}).",
        "",
        "| views | sessions | elementwise min | learned chain | unregistered (aligned share) | registered | "
        "interval held: unregistered / registered |",
        "|---|---|---|---|---|---|---|",
    ]
    for length in lengths(metrics):
        present = [rows[key] for key in (f"{length}/mesh", f"{length}/remeshed") if key in rows]

        def both(key: str, present: list[dict] = present) -> str:
            return " / ".join(percent(cell[key]) for cell in present)

        count = " / ".join(str(cell["sessions"]) for cell in present)
        lines.append(
            f"| {length} | {count} | {both('elementwise_min')} | {both('learned_chain')} | {both('unregistered')} "
            f"({both('aligned')}) | {both('registered')} | {both('unregistered_held')}; {both('registered_held')} |"
        )
    verdicts = "; ".join(f"{goal}: {'met' if met else '**not met**'}" for goal, met in goals(metrics).items())
    lines += ["", f"Goals: {verdicts}.", END]
    return "\n".join(lines)
