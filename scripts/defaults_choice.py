"""The table that chooses the processing defaults: each candidate setting (receive f-number,
partial-volume correction, Doppler kernel) scored on every study at once, on the seeds held out
for the choice (6–10), so that the seeds 1–5 of the other tables stay a fair report.

Its runs are kept in docs/results/metrics/paper/choice/ (scripts/paper-results --add
choice/NAME ...): spiral, dealiasing, network and brain parts of `pcuvd paper` with the options
of a candidate. A run is matched to a candidate by the settings its metrics.json states, never
by file name. One spiral run serves every Doppler kernel (its averaging scores). The vessel
network has no column: its scores are RI maps, whose windows keep their own kernel and, as
`pcuvd process` does, no correction, so of these options only the f-number changes them (the
network page's F# 1.0 row).

Python 3, standard library only.
"""

from __future__ import annotations

import json
from statistics import mean

from paper_series import (DEFAULTS, FORMER_DEFAULTS, METRICS, f2, kernel_name, options_label,
                          seeds_text)

CHOICE = METRICS / "choice"

# (f-number, partial-volume correction, Doppler kernel): the former defaults first.
CANDIDATES = [
    (1.5, False, (1, 1)),
    (1.5, False, (5, 1)),
    (1.5, True, (1, 1)),
    (1.5, True, (5, 1)),
    (1.0, True, (1, 1)),
    (1.0, True, (5, 1)),
    (0.75, True, (1, 1)),
    (0.75, True, (5, 1)),
]


def choice_runs() -> list[dict]:
    """Every kept run of the choice."""
    return [json.loads(p.read_text()) for p in sorted(CHOICE.glob("*.json"))]


def label(candidate: tuple) -> str:
    f_number, corrected, kernel = candidate
    options = {"f_number": f_number, "partial_volume": corrected, "doppler_kernel": list(kernel)}
    text = options_label(options)
    if options == DEFAULTS:
        return f"**{text} (the defaults)**"
    return text + (" (the former defaults)" if options == FORMER_DEFAULTS else "")


def mean_range(values: list[float]) -> str:
    if len(values) == 1:
        return f2(values[0])
    return f"{f2(mean(values))} ({f2(min(values))}–{f2(max(values))})"


def spiral_cell(runs: list[dict], candidate: tuple) -> str:
    """PC-UVD's Vx / Vz RMSE at the paper's baseline (UVD's Vx calibrated to 5.70 mm/s with the
    candidate's kernel), over the seeds."""
    f_number, corrected, kernel = candidate
    scores, seeds = [], []
    for r in runs:
        m = r["metrics"]
        if "averaging" not in m or (m["f_number"], m["partial_volume"]) != (f_number, corrected):
            continue
        if (m["doppler_estimator"], m["frames"], m["motion"]) != ("loupas", 100, "PerEvent"):
            continue
        entry = next((a for a in m["averaging"] if tuple(a["kernel"]) == kernel), None)
        if entry is None or not entry["calibrated"] or not entry["calibrated"]["rmse_mm_s"]:
            continue
        scores.append(entry["calibrated"]["rmse_mm_s"]["pcuvd_irls"])
        seeds.append(m["seed"])
    if not scores:
        return "–"
    return (f"{mean_range([s['vx'] for s in scores])} / {f2(mean(s['vz'] for s in scores))} "
            f"({seeds_text(sorted(seeds))})")


def tube_cell(runs: list[dict], candidate: tuple) -> str:
    """The dealiased parabolic tube at 3× v_N, 400 frames, no noise: UVD's lumen within 10 % of
    the peak, worst and best seed."""
    f_number, corrected, kernel = candidate
    values, seeds = [], []
    for r in runs:
        d = r["metrics"].get("dealias")
        if d is None:
            continue
        s = d["settings"]
        if (s["f_number"], s["partial_volume"], tuple(s["doppler_kernel"]), s["frames"],
                s["tube_profile"], s["dealias"]) != (f_number, corrected, kernel, 400,
                                                     "parabolic", "auto"):
            continue
        for row in d["rows"]:
            if (row["multiple"], row["noise_db"], row["method"]) == (3.0, None, "uvd_ls"):
                values.append(row["on"]["within_10pct_of_peak"])
                seeds.append(row["seed"])
    if not values:
        return "–"
    return f"{100 * min(values):.1f}–{100 * max(values):.1f} % ({seeds_text(sorted(seeds))})"


def brain_cell(runs: list[dict], candidate: tuple) -> str:
    """The virtual rat brain's vector RMSE, UVD → PC-UVD: the deepest third, every lumen pixel."""
    f_number, corrected, kernel = candidate
    for r in runs:
        b = r["metrics"].get("brain")
        if b is None or "processing" not in b:
            continue
        p = b["processing"]
        if (p["f_number"], p["partial_volume"] == "on", p["doppler_kernel"]) != (
                f_number, corrected, kernel_name(list(kernel))):
            continue
        deep, every = b["vector_by_depth"][-1], b["vector_all"]
        return (f"{f2(deep['uvd']['rmse_mm_s'])} → {f2(deep['pcuvd']['rmse_mm_s'])} "
                f"({deep['group']}); {f2(every['uvd']['rmse_mm_s'])} → "
                f"{f2(every['pcuvd']['rmse_mm_s'])} (all lumen)")
    return "–"


def defaults_choice(runs: list[dict]) -> dict | None:
    """One row per candidate measured, one column per study: what each option improves and
    worsens."""
    if not runs:
        return None
    rows = [[label(c), spiral_cell(runs, c), tube_cell(runs, c), brain_cell(runs, c)]
            for c in CANDIDATES]
    commits = sorted({r["commit"] for r in runs})
    cpus = sorted({r["cpu"] for r in runs})
    return {
        "id": "defaults-choice",
        "title": "Choosing the defaults: every study at each candidate setting, on the seeds "
                 "held out for the choice",
        "command": "`pcuvd paper --part spiral|dealias|brain --seed N` (dealiasing: "
                   "`--frames 400 --dealias-multiples 3 --dealias-noise-db off --dealias-seeds "
                   "6,7,8`) with the candidate's `--f-number`, `--partial-volume` and "
                   "`--doppler-kernel`",
        "commit": ", ".join(commits),
        "cpu": ", ".join(cpus),
        "units": "spiral: PC-UVD's RMSE Vx (mean and range over the seeds) / Vz in mm/s at the "
                 "paper's baseline (UVD's Vx brought to 5.70 mm/s with the same kernel), target "
                 "≤ 3.22 / 1.59; tube: the dealiased parabolic tube's lumen within 10 % of the "
                 "peak at 3× v_N (UVD), worst–best seed, target ≥ 95 %; brain: vector RMSE in "
                 "mm/s, UVD → PC-UVD (scenario `rat-brain`, one simulation); – not measured",
        "columns": ["candidate", "spiral (PC-UVD Vx / Vz)", "tube at 3× v_N, 400 frames",
                    "brain vector RMSE"],
        "rows": [row for row in rows if any(cell != "–" for cell in row[1:])],
    }
