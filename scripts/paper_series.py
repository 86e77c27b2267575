"""The tables scripts/paper-results builds from several runs of `pcuvd paper`: the spiral over
seeds 1–5 with each estimator, with the partial-volume correction and at other apertures; the
dealiasing tube's variants.

A run is a kept record (docs/results/metrics/paper/*.json and seeds/*.json, each holding the
run's metrics.json). Runs are grouped by the settings their metrics.json states (estimator,
correction, f-number, motion, decoding, kernel, frames), never by file name, so a table cannot mix
a run made with other options into its mean.

Python 3, standard library only.
"""

from __future__ import annotations

import json
from pathlib import Path
from statistics import mean

from metrics_record import ROOT

METRICS = ROOT / "docs" / "results" / "metrics" / "paper"
SEEDS = METRICS / "seeds"

# The paper's Table 2 (spiral, 8 angles): UVD and PC-UVD RMSE in mm/s, the improvement in %.
PAPER_UVD = (5.70, 2.28)
PAPER_PCUVD = (3.22, 1.59)
PAPER_IMPROVEMENT = (43.5, 30.3)


def minus(text: str) -> str:
    """Negative numbers with the minus sign the pages use (−), not a hyphen."""
    return text.replace("-", "−")


def f2(x) -> str:
    return "–" if x is None else minus(f"{x:.2f}")


def db(x: float) -> str:
    return minus(f"{x:+.2f} dB")


def spread(values: list[float]) -> str:
    """A mean with its range, `3.81 (3.76–3.86)`; a single value alone."""
    if len(values) == 1:
        return f2(values[0])
    return f"{f2(mean(values))} ({f2(min(values))}–{f2(max(values))})"


def vector(values: list[dict], range_of_vx: bool = False) -> str:
    """Mean Vx / Vz of several {vx, vz}, Vx with its range when asked."""
    vx = [v["vx"] for v in values]
    vz = [v["vz"] for v in values]
    return f"{spread(vx) if range_of_vx else f2(mean(vx))} / {f2(mean(vz))}"


def improvement(values: list[dict]) -> str:
    return minus(f"{mean(v['vx'] for v in values):.1f} / {mean(v['vz'] for v in values):.1f} %")


def runs() -> list[dict]:
    """Every kept run of `pcuvd paper` that holds the spiral's numbers."""
    paths = sorted(METRICS.glob("*.json")) + sorted(SEEDS.glob("*.json"))
    kept = [json.loads(p.read_text()) for p in paths]
    return [r for r in kept if "calibrated" in r["metrics"]]


def spiral_series(all_runs: list[dict], estimator: str = "loupas", partial_volume: bool = False,
                  f_number: float = 1.5) -> list[dict]:
    """The spiral runs at the paper's acquisition and the defaults but for the named options,
    one per seed (the first kept when a seed was run twice), by seed."""
    by_seed: dict[int, dict] = {}
    for r in all_runs:
        m = r["metrics"]
        if (m["doppler_estimator"], m["partial_volume"], m["f_number"]) != (
                estimator, partial_volume, f_number):
            continue
        if (m["motion"], m["event_alignment"], m["doppler_kernel"], m["frames"]) != (
                "PerEvent", "mid-frame", [1, 1], 100):
            continue
        by_seed.setdefault(m["seed"], r)
    return [by_seed[s] for s in sorted(by_seed)]


def seeds_of(series: list[dict]) -> list[int]:
    return [r["metrics"]["seed"] for r in series]


def seeds_text(seeds: list[int]) -> str:
    """`seeds 1–5`, `seeds 1, 3` or `seed 2`."""
    if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"seeds {seeds[0]}–{seeds[-1]}"
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


def where_many(series: list[dict], command: str) -> dict:
    """The command, and each commit and CPU the series was measured with; where they differ, the
    runs each names (by their options, then seeds)."""
    def grouped(key: str) -> str:
        values: dict[str, list[dict]] = {}
        for r in series:
            values.setdefault(r[key], []).append(r)
        if len(values) == 1:
            return next(iter(values))
        return "; ".join(f"{v} ({runs_text(rs)})" for v, rs in values.items())
    return {"command": command, "commit": grouped("commit"), "cpu": grouped("cpu")}


def runs_text(runs_: list[dict]) -> str:
    """Runs named by their options that differ from the defaults, then their seeds."""
    by_options: dict[str, list[int]] = {}
    for r in runs_:
        m = r["metrics"]
        options = [f"{m['doppler_estimator']}" if m["doppler_estimator"] != "loupas" else "",
                   "partial volume" if m.get("partial_volume") else "",
                   f"F# {f_number_text(m['f_number'])}" if m.get("f_number", 1.5) != 1.5 else ""]
        name = ", ".join(o for o in options if o)
        by_options.setdefault(name, []).append(m["seed"])
    return "; ".join(f"{name + ' ' if name else ''}{seeds_text(seeds)}"
                     for name, seeds in by_options.items())


def f_number_text(f_number: float) -> str:
    """An f-number as the options write it: 1.5, 1.0, 0.75."""
    text = f"{f_number:g}"
    return text if "." in text else f"{text}.0"


def kernel_name(kernel: list[int]) -> str:
    return f"{kernel[0]}x{kernel[1]}"


def averaged(run: dict, kernel: list[int]) -> dict:
    """The run's scores with one averaging kernel (`averaging` in metrics.json)."""
    return next(a for a in run["metrics"]["averaging"] if a["kernel"] == kernel)


def calibrated_baseline(all_runs: list[dict]) -> dict:
    """Each seed at the paper's calibrated baseline, Loupas and Kasai, with their means."""
    rows = []
    for estimator in ("loupas", "kasai"):
        series = spiral_series(all_runs, estimator)
        for r in series:
            c = r["metrics"]["calibrated"]
            rows.append([str(r["metrics"]["seed"]), estimator, db(c["noise_db"]),
                         vector([c["rmse_mm_s"]["uvd_ls"]]),
                         vector([c["rmse_mm_s"]["pcuvd_irls"]]),
                         improvement([c["improvement_pct"]])])
        cs = [r["metrics"]["calibrated"] for r in series]
        rows.append([f"**mean, {seeds_text(seeds_of(series))}**", f"**{estimator}**",
                     db(mean(c["noise_db"] for c in cs)),
                     vector([c["rmse_mm_s"]["uvd_ls"] for c in cs]),
                     f"**{vector([c['rmse_mm_s']['pcuvd_irls'] for c in cs], True)}**",
                     f"**{improvement([c['improvement_pct'] for c in cs])}**"])
    rows.append(["paper", "–", "–", f"{f2(PAPER_UVD[0])} / {f2(PAPER_UVD[1])}",
                 f"{f2(PAPER_PCUVD[0])} / {f2(PAPER_PCUVD[1])}",
                 f"{PAPER_IMPROVEMENT[0]} / {PAPER_IMPROVEMENT[1]} %"])
    both = spiral_series(all_runs) + spiral_series(all_runs, "kasai")
    return {
        "id": "calibrated-baseline",
        "title": "The paper's headline at its own baseline (`--calibrate-uvd-vx 5.7`)",
        **where_many(both, "`pcuvd paper --part spiral --seed N [--doppler-estimator kasai]`"),
        "units": "calibrated noise level in dB; RMSE in mm/s (UVD = conventional + LS, PC-UVD = "
                 "coded + IRLS; the mean's PC-UVD Vx with its range over the seeds); "
                 "improvement in %",
        "columns": ["seed", "estimator", "calibrated level", "UVD Vx / Vz", "PC-UVD Vx / Vz",
                    "improvement Vx / Vz"],
        "rows": rows,
    }


def kernel_rows(series: list[dict]) -> list[list[str]]:
    """Per averaging kernel over a series of seeds: its extent, PC-UVD without noise, the level
    where UVD with that kernel reads the paper's Vx, UVD's Vz and PC-UVD there, the improvement
    and the kernel's own resolution cost."""
    kernels = [a["kernel"] for a in series[0]["metrics"]["averaging"]]
    scores = {kernel_name(k): [averaged(r, k) for r in series] for k in kernels}
    best = min(scores, key=lambda k: mean(
        a["calibrated"]["rmse_mm_s"]["pcuvd_irls"]["vx"] for a in scores[k]))
    rows = []
    for k in kernels:
        name = kernel_name(k)
        a = scores[name]
        mark = "**" if name == best else ""
        extent = a[0]["extent_mm"]
        rows.append([
            f"{mark}{name}{mark}" + (" (pixel-wise, the paper's)" if k == [1, 1] else ""),
            f"{extent[0]:.2f} × {extent[1]:.2f} mm",
            vector([x["floor_mm_s"]["pcuvd_irls"] for x in a]),
            db(mean(x["calibrated"]["noise_db"] for x in a)),
            f2(mean(x["calibrated"]["rmse_mm_s"]["uvd_ls"]["vz"] for x in a)),
            mark + vector([x["calibrated"]["rmse_mm_s"]["pcuvd_irls"] for x in a], True) + mark,
            improvement([x["calibrated"]["improvement_pct"] for x in a]),
            vector([x["blur_rmse_mm_s"] for x in a]),
        ])
    return rows


def averaging_kernels(all_runs: list[dict]) -> dict:
    series = spiral_series(all_runs)
    return {
        "id": "averaging-kernels",
        "title": f"Spatial averaging of the autocorrelation, {seeds_text(seeds_of(series))}",
        **where_many(series, "`pcuvd paper --part spiral --seed N` (`--averaging-kernels`, "
                             "default 1x1,3x1,5x1,7x1,3x3)"),
        "units": "RMSE and resolution cost in mm/s (mean over the seeds, PC-UVD's Vx range in "
                 "brackets; the lowest PC-UVD Vx in bold); level in dB; improvement in %",
        "columns": ["kernel (depth × lateral)", "extent", "no noise, PC-UVD Vx / Vz",
                    "calibrated level", "UVD Vz there", "PC-UVD Vx / Vz there",
                    "improvement Vx / Vz", "resolution cost Vx / Vz"],
        "rows": kernel_rows(series) + [
            ["paper", "–", "–", "–", f2(PAPER_UVD[1]), f"{f2(PAPER_PCUVD[0])} / "
             f"{f2(PAPER_PCUVD[1])}", f"{PAPER_IMPROVEMENT[0]} / {PAPER_IMPROVEMENT[1]} %", "–"]],
    }


def correction_row(label: str, series: list[dict]) -> list[str]:
    """A series at the calibrated baseline: level, UVD, PC-UVD, improvement, the 5x1 kernel at
    its own baseline and PC-UVD without noise."""
    cs = [r["metrics"]["calibrated"] for r in series]
    five = [averaged(r, [5, 1]) for r in series]
    pixel = [averaged(r, [1, 1]) for r in series]
    return [label, db(mean(c["noise_db"] for c in cs)),
            vector([c["rmse_mm_s"]["uvd_ls"] for c in cs]),
            vector([c["rmse_mm_s"]["pcuvd_irls"] for c in cs], True),
            improvement([c["improvement_pct"] for c in cs]),
            vector([a["calibrated"]["rmse_mm_s"]["pcuvd_irls"] for a in five], True),
            vector([a["floor_mm_s"]["pcuvd_irls"] for a in pixel])]


# The columns of correction_row after its label.
CORRECTION_COLUMNS = ["calibrated level", "UVD Vx / Vz", "PC-UVD Vx / Vz", "improvement Vx / Vz",
                      "PC-UVD, 5x1 kernel at its own baseline", "PC-UVD without noise"]


def partial_volume(all_runs: list[dict]) -> dict | None:
    series = spiral_series(all_runs, partial_volume=True)
    if not series:
        return None
    rows = [correction_row(str(r["metrics"]["seed"]), [r]) for r in series]
    rows.append(correction_row(f"**mean, {seeds_text(seeds_of(series))}**", series))
    plain = spiral_series(all_runs)
    rows.append(correction_row(f"without the correction (mean, {seeds_text(seeds_of(plain))})", plain))
    rows.append(["paper", "–", f"{f2(PAPER_UVD[0])} / {f2(PAPER_UVD[1])}",
                 f"{f2(PAPER_PCUVD[0])} / {f2(PAPER_PCUVD[1])}",
                 f"{PAPER_IMPROVEMENT[0]} / {PAPER_IMPROVEMENT[1]} %", "–", "–"])
    return {
        "id": "partial-volume",
        "title": f"The partial-volume correction, {seeds_text(seeds_of(series))}",
        **where_many(series, "`pcuvd paper --part spiral --partial-volume on --seed N`"),
        "units": "calibrated level in dB; RMSE in mm/s (means give PC-UVD's Vx range over the "
                 "seeds); improvement in %",
        "columns": ["seed", *CORRECTION_COLUMNS],
        "rows": rows,
    }


def spiral_f_number(all_runs: list[dict]) -> dict | None:
    """The spiral at each receive f-number kept, with and without the correction."""
    cases = sorted({(r["metrics"]["f_number"], r["metrics"]["partial_volume"]) for r in all_runs
                    if r["metrics"]["doppler_estimator"] == "loupas"},
                   key=lambda c: (-c[0], c[1]))
    rows, measured = [], []
    for f_number, correction in cases:
        series = spiral_series(all_runs, partial_volume=correction, f_number=f_number)
        if not series:
            continue
        measured += series
        label = (f_number_text(f_number) + (" (default)" if f_number == 1.5 else "")
                 + (", `--partial-volume on`" if correction else "")
                 + f" ({seeds_text(seeds_of(series))})")
        rows.append(correction_row(label, series))
    if len(rows) < 2:  # nothing to compare the default aperture with
        return None
    return {
        "id": "spiral-f-number",
        "title": "The spiral at other receive apertures",
        **where_many(measured, "`pcuvd paper --part spiral --f-number F [--partial-volume on] "
                               "--seed N`"),
        "units": "calibrated level in dB (calibrated again at each aperture); RMSE in mm/s "
                 "(PC-UVD = coded + IRLS; means over the seeds, PC-UVD's Vx range in "
                 "brackets); improvement in %",
        "columns": ["F#", *CORRECTION_COLUMNS],
        "rows": rows,
    }


def kernel_correction(all_runs: list[dict]) -> dict | None:
    """Conventional UVD (LS) without noise through each kernel, at F# 1.0, with and without
    the correction: the averaging scores' floors of one seed."""
    plain = spiral_series(all_runs, f_number=1.0)
    corrected = spiral_series(all_runs, partial_volume=True, f_number=1.0)
    if not plain or not corrected:
        return None
    a, b = plain[0], corrected[0]
    rows = [[kernel_name(k["kernel"]), vector([k["floor_mm_s"]["uvd_ls"]]),
             vector([averaged(b, k["kernel"])["floor_mm_s"]["uvd_ls"]])]
            for k in a["metrics"]["averaging"]]
    return {
        "id": "kernel-correction",
        "title": f"The correction with a Doppler kernel (noiseless spiral, F# 1.0, seed "
                 f"{a['metrics']['seed']}, conventional UVD)",
        **where_many([a, b], "`pcuvd paper --part spiral --f-number 1.0 [--partial-volume on] "
                             "--seed 1` (each kernel's score without noise)"),
        "units": "Vx / Vz RMSE in mm/s (conventional + LS)",
        "columns": ["kernel", "no correction", "`--partial-volume on`"],
        "rows": rows,
    }


def dealias_runs() -> list[dict]:
    """Every kept run of the dealiasing part (`dealias*.json` and the files of dealias/)."""
    paths = sorted(METRICS.glob("dealias*.json")) + sorted((METRICS / "dealias").glob("*.json"))
    kept = [json.loads(p.read_text()) for p in paths]
    return [r for r in kept if "dealias" in r["metrics"]]


def dealias_run(profile: str, noise_levels: int, all_runs: list[dict]) -> dict | None:
    """The dealiasing run of the defaults over several seeds for a tube profile: the one with the
    most seeds among those with at least `noise_levels` noise levels."""
    def plain(r: dict) -> bool:
        s = r["metrics"]["dealias"]["settings"]
        return (s["tube_profile"] == profile and s["frames"] == 100 and s["f_number"] == 1.5
                and not s["partial_volume"] and s["doppler_kernel"] == [1, 1]
                and len(s["noise_db"]) >= noise_levels)
    found = [r for r in all_runs if plain(r)]
    return max(found, key=lambda r: len(r["metrics"]["dealias"]["settings"]["seeds"]),
               default=None)


def longer_study(all_runs: list[dict]) -> dict | None:
    """The dealiasing study over several seeds with 400 frames, F# 0.75 and the partial-volume
    correction: the settings that meet the 3× target on the parabolic tube."""
    def longer(r: dict) -> bool:
        s = r["metrics"]["dealias"]["settings"]
        return ((s["frames"], s["f_number"], s["partial_volume"]) == (400, 0.75, True)
                and len(s["seeds"]) > 1)
    return next((r for r in all_runs if longer(r)), None)


def tube_at_apertures(all_runs: list[dict], multiple: float = 3.0) -> dict | None:
    """Conventional UVD (LS), dealiased, without noise, on the parabolic tube at `multiple` ×
    v_N: the lumen within 10 % of the peak for each frame count and correction (rows) and
    receive f-number (columns), the mean over the run's seeds."""
    cells: dict[tuple, dict[float, dict[int, float]]] = {}
    measured = []
    for r in all_runs:
        d = r["metrics"]["dealias"]
        s = d["settings"]
        if s["tube_profile"] != "parabolic":
            continue
        rows = [x for x in d["rows"] if x["multiple"] == multiple and x["noise_db"] is None
                and x["method"] == "uvd_ls"]
        if not rows:
            continue
        measured.append(r)
        key = (s["frames"], s["partial_volume"], kernel_name(s["doppler_kernel"]))
        by_seed = cells.setdefault(key, {}).setdefault(s["f_number"], {})
        for x in rows:  # a seed run twice at the same settings counts once
            by_seed.setdefault(x["seed"], 100 * x["on"]["within_10pct_of_peak"])
    if not measured:
        return None
    apertures = sorted({f for row in cells.values() for f in row}, reverse=True)

    def cell(by_seed: dict[int, float] | None) -> str:
        if not by_seed:
            return "–"
        values = list(by_seed.values())
        if len(values) == 1:
            return f"{values[0]:.1f} %"
        return f"{mean(values):.1f} % ({min(values):.1f}–{max(values):.1f}, {len(values)} seeds)"

    rows = [[f"{frames} frames" + (", `--partial-volume on`" if pv else "")
             + ("" if kernel == "1x1" else f", `--doppler-kernel {kernel}`"),
             *[cell(cells[(frames, pv, kernel)].get(f)) for f in apertures]]
            for frames, pv, kernel in sorted(cells)]
    commits = sorted({r["commit"] for r in measured})
    return {
        "id": "parabolic-tube-3x",
        "title": f"Parabolic tube at {multiple:g}× v_N without noise, conventional UVD (LS) "
                 f"dealiased: lumen within 10 % of the peak",
        "command": "`pcuvd paper --part dealias --dealias-noise-db off --f-number F [--frames N] "
                   "[--partial-volume on] [--doppler-kernel K] --dealias-seeds S` (the cell "
                   "names the seeds when more than one)",
        "commit": ", ".join(commits),
        "cpu": "; ".join(sorted({r["cpu"] for r in measured})),
        "units": "fraction of the lumen within 10 % of the peak speed (%): the mean, and the "
                 "range over the seeds",
        "columns": ["frames, correction", *[f"F# {f_number_text(f)}" for f in apertures]],
        "rows": rows,
    }


def value_range(values: list[float], unit: str = "", scale: float = 1.0) -> str:
    values = [scale * v for v in values]
    if len(values) == 1:
        return f"{f2(values[0])}{unit}"
    return f"{f2(min(values))}–{f2(max(values))}{unit}"


def shares(run: dict | None, multiple: float, noise_db, method: str = "uvd_ls",
           key: str = "within_10pct_of_peak") -> list[float]:
    """A dealiasing run's dealiased lumen fractions at one speed and noise level, one per seed."""
    if run is None:
        return []
    return [x["on"][key] for x in run["metrics"]["dealias"]["rows"]
            if x["multiple"] == multiple and x["noise_db"] == noise_db and x["method"] == method]


def share_text(values: list[float]) -> str:
    """Lumen fractions of one or more seeds, in % with one decimal: `99.0–100.0 % (5 seeds)`."""
    if not values:
        return "not measured"
    low, high = 100 * min(values), 100 * max(values)
    if len(values) == 1:
        return f"{low:.1f} %"
    return f"{low:.1f}–{high:.1f} % ({len(values)} seeds)"


def holds(ok: bool) -> str:
    return "holds" if ok else "not met"


# Targets a test asserts on every CI run (the slow tier); its doc comment gives what it measured.
TESTED_TARGETS = [
    ["noiseless translating block, 2–12 mm, 5–40 mm/s: each angle's projection within 1 %, "
     "vector within 1 % and 1°",
     "holds: asserted by `translating_block_reads_projections_and_vector_within_one_percent`",
     "holds: the same test at F# 1.0"],
    ["the same where attenuation moved the echo spectrum 6 % below f_c",
     "holds: `attenuated_block_reads_within_one_percent_where_the_spectrum_has_moved`", "–"],
    ["decoded projections within 1 % of conventional ones",
     "holds from 4 frames: `decoded_projections_match_conventional_from_twelve_frames`", "–"],
]


def at_a_glance(all_runs: list[dict], dealiasing: list[dict]) -> dict | None:
    """The accuracy targets, each scored from the kept runs (or named with the test that
    asserts it)."""
    plain = spiral_series(all_runs)
    corrected = spiral_series(all_runs, partial_volume=True)
    plug = dealias_run("plug", 1, dealiasing)
    study = dealias_run("parabolic", 3, dealiasing)
    if not plain or not corrected or plug is None or study is None:
        return None
    longer_run = longer_study(dealiasing)

    def calibrated(series: list[dict], kernel: list[int], axis: str) -> list[float]:
        return [averaged(r, kernel)["calibrated"]["rmse_mm_s"]["pcuvd_irls"][axis]
                for r in series]

    vz, vx = calibrated(plain, [1, 1], "vz"), calibrated(plain, [1, 1], "vx")
    vx5 = calibrated(plain, [5, 1], "vx")
    vx_pv, vx_pv5 = calibrated(corrected, [1, 1], "vx"), calibrated(corrected, [5, 1], "vx")
    seeds = seeds_text(seeds_of(plain))
    plug3, parabolic3 = shares(plug, 3.0, None), shares(study, 3.0, None)
    noisy = [(n, shares(study, 3.0, n)) for n in sorted(
        {x["noise_db"] for x in study["metrics"]["dealias"]["rows"] if x["noise_db"] is not None})]
    slow = [x for x in study["metrics"]["dealias"]["rows"] if x["multiple"] == 1.0]
    untouched = all(x["unwrapped_lumen_pixels"] == 0 for x in slow)
    def verdict(values: list[float]) -> str:
        return f"{holds(bool(values) and min(values) >= 0.95)}: {share_text(values)}"

    longer_text = "not measured" if longer_run is None else (
        "parabolic, `--frames 400 --f-number 0.75 --partial-volume on`, "
        + verdict(shares(longer_run, 3.0, None)))
    longer_noisy = "–" if longer_run is None else "parabolic, the same settings: " + "; ".join(
        f"{g_db(n)} {verdict(shares(longer_run, 3.0, n))}"
        for n in sorted({x["noise_db"] for x in longer_run["metrics"]["dealias"]["rows"]
                         if x["noise_db"] is not None}))
    rows = TESTED_TARGETS + [
        ["PC-UVD at the paper's baseline: Vz ≤ 1.59 mm/s",
         f"{holds(max(vz) <= 1.59)}: {value_range(vz)} ({seeds})", "–"],
        ["PC-UVD at the paper's baseline: Vx ≤ 3.22 mm/s",
         f"{holds(max(vx) <= 3.22)}: {value_range(vx)}",
         f"`--doppler-kernel 5x1`: {value_range(vx5)}; `--partial-volume on`: "
         f"{value_range(vx_pv)}"],
        ["PC-UVD at the paper's baseline: Vx ≤ 2.5 mm/s (the aim)",
         f"{holds(max(vx) <= 2.5)}",
         f"`--partial-volume on --doppler-kernel 5x1`: {value_range(vx_pv5)}"],
        ["dealiased tube at 3× v_N: ≥ 95 % of the lumen within 10 % of the peak, no noise",
         f"plug flow {verdict(plug3)}; parabolic {verdict(parabolic3)}", longer_text],
        ["the same with noise: ≥ 95 %",
         "parabolic: " + "; ".join(f"{g_db(n)} {verdict(v)}" for n, v in noisy),
         longer_noisy],
        ["dealiasing leaves slow flow (1× v_N) as it was",
         "holds (nothing unwrapped)" if untouched else "not met (pixels unwrapped at 1×)", "–"],
    ]
    brain = brain_runs()
    rows += brain_rows(brain)
    measured = plain + corrected + [plug, study] + list(brain.values())
    return {
        "id": "at-a-glance",
        "title": "The accuracy targets at a glance",
        "command": "per row: the named test (slow tier, every CI run); `pcuvd paper --part "
                   "spiral --seed N [--partial-volume on]`; `pcuvd paper --part dealias "
                   "--dealias-seeds ...` with the options in the row; `pcuvd paper --part brain "
                   "[--brain-svd-low similarity]` (the [virtual rat brain](brain.md)'s runs)",
        "commit": ", ".join(sorted({r["commit"] for r in measured})),
        "cpu": "; ".join(sorted({r["cpu"] for r in measured})),
        "units": "RMSE in mm/s (ranges over the seeds); fractions of the lumen in %",
        "columns": ["target", "at the defaults", "with other settings"],
        "rows": rows,
    }


BRAIN = ROOT / "docs" / "results" / "metrics" / "brain"


def brain_runs() -> dict[str, dict]:
    """The brain's kept default run (`auto`) and its similarity cut-off run, where kept."""
    return {name: json.loads((BRAIN / f"{name}.json").read_text())
            for name in ("auto", "similarity") if (BRAIN / f"{name}.json").exists()}


def brain_rows(runs_: dict[str, dict]) -> list[list[str]]:
    """The virtual rat brain's targets, from its default run and its similarity cut-off run."""
    if "auto" not in runs_:
        return []
    default = runs_["auto"]["brain"]
    similarity = runs_["similarity"]["brain"] if "similarity" in runs_ else None

    def deepest(b: dict) -> str:
        g = b["vector_by_depth"][-1]
        gain = g["improvement_pct"]
        side = "below" if gain is not None and gain >= 0 else "above"
        return (f"{holds(gain is not None and gain >= 30)}: PC-UVD {f2(g['pcuvd']['rmse_mm_s'])} "
                f"against UVD {f2(g['uvd']['rmse_mm_s'])} mm/s ({g['group']}; "
                f"{abs(gain or 0):.0f} % {side})")

    def ri(b: dict) -> str:
        groups = {g["group"]: g["pcuvd"] for g in b["ri"] if g["pcuvd"]}
        every, one = groups.get("all lumen pixels"), groups.get(
            "all lumen pixels, one class in the beam")
        text = (f"{holds(every['median_abs_error'] <= 0.05 and every['class_accuracy'] >= 0.95)}"
                f": {every['median_abs_error']:.2f}, {100 * every['class_accuracy']:.0f} % "
                f"(PC-UVD, every lumen pixel)")
        if one:
            text += (f"; {one['median_abs_error']:.2f}, {100 * one['class_accuracy']:.0f} % where "
                     f"one class fills the elevation beam")
        return text

    return [
        ["virtual rat brain (`paper --part brain`): PC-UVD's vector RMSE ≥ 30 % below UVD's in "
         "the deepest third", deepest(default),
         "–" if similarity is None else "`--brain-svd-low similarity`: " + deepest(similarity)],
        ["virtual rat brain: median |ΔRI| ≤ 0.05, ≥ 95 % classed right", ri(default),
         "–" if similarity is None else "`--brain-svd-low similarity`: " + ri(similarity)],
    ]


def g_db(noise_db: float) -> str:
    """A noise level as the pages write it: `−10 dB`, `0 dB`, `+5 dB`."""
    return minus(f"{noise_db:+g} dB") if noise_db else "0 dB"
