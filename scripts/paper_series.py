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

# The processing options of a run that the defaults set: receive f-number, partial-volume
# correction, Doppler kernel. The defaults (chosen on seeds 6–10, the accuracy page's choice
# table) and the ones they replaced, whose kept runs stay as the comparison.
DEFAULTS = {"f_number": 1.0, "partial_volume": True, "doppler_kernel": [5, 1]}
FORMER_DEFAULTS = {"f_number": 1.5, "partial_volume": False, "doppler_kernel": [1, 1]}


def options_text(options: dict) -> str:
    """Processing options as `pcuvd paper` takes them."""
    return (f"`--f-number {f_number_text(options['f_number'])} --partial-volume "
            f"{'on' if options['partial_volume'] else 'off'} --doppler-kernel "
            f"{kernel_name(options['doppler_kernel'])}`")


def options_label(options: dict) -> str:
    """Processing options as the tables name them: `F# 1.0, partial volume on, 5x1`."""
    return (f"F# {f_number_text(options['f_number'])}, partial volume "
            f"{'on' if options['partial_volume'] else 'off'}, "
            f"{kernel_name(options['doppler_kernel'])}")


def options_of(settings: dict) -> dict:
    """The processing options a run's settings state (a record older than the network's
    statement of its kernel and correction ran at the former defaults)."""
    return {key: settings.get(key, FORMER_DEFAULTS[key]) for key in DEFAULTS}


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


def spiral_series(all_runs: list[dict], estimator: str = "loupas",
                  options: dict | None = None) -> list[dict]:
    """The spiral runs at the paper's acquisition with these processing options (default: the
    defaults) and the defaults otherwise, one per seed (the first kept when a seed was run
    twice), by seed."""
    options = DEFAULTS if options is None else options
    by_seed: dict[int, dict] = {}
    for r in all_runs:
        m = r["metrics"]
        if m["doppler_estimator"] != estimator or options_of(m) != options:
            continue
        if (m["motion"], m["event_alignment"], m["frames"]) != ("PerEvent", "mid-frame", 100):
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
        o = options_of(m)
        options = [f"{m['doppler_estimator']}" if m["doppler_estimator"] != "loupas" else "",
                   "" if o == DEFAULTS else
                   "former defaults" if o == FORMER_DEFAULTS else options_label(o)]
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
    """Each seed at the paper's calibrated baseline: Loupas and Kasai at the defaults, then at
    the former defaults, each with its mean."""
    rows, measured = [], []
    for estimator, options, name in (("loupas", DEFAULTS, "the defaults"),
                                     ("kasai", DEFAULTS, "the defaults"),
                                     ("loupas", FORMER_DEFAULTS, "former defaults"),
                                     ("kasai", FORMER_DEFAULTS, "former defaults")):
        series = spiral_series(all_runs, estimator, options)
        if not series:
            continue
        measured += series
        setting = f"{estimator}, {name}"
        for r in series:
            c = r["metrics"]["calibrated"]
            rows.append([str(r["metrics"]["seed"]), setting, db(c["noise_db"]),
                         vector([c["rmse_mm_s"]["uvd_ls"]]),
                         vector([c["rmse_mm_s"]["pcuvd_irls"]]),
                         improvement([c["improvement_pct"]])])
        cs = [r["metrics"]["calibrated"] for r in series]
        rows.append([f"**mean, {seeds_text(seeds_of(series))}**", f"**{setting}**",
                     db(mean(c["noise_db"] for c in cs)),
                     vector([c["rmse_mm_s"]["uvd_ls"] for c in cs]),
                     f"**{vector([c['rmse_mm_s']['pcuvd_irls'] for c in cs], True)}**",
                     f"**{improvement([c['improvement_pct'] for c in cs])}**"])
    rows.append(["paper", "–", "–", f"{f2(PAPER_UVD[0])} / {f2(PAPER_UVD[1])}",
                 f"{f2(PAPER_PCUVD[0])} / {f2(PAPER_PCUVD[1])}",
                 f"{PAPER_IMPROVEMENT[0]} / {PAPER_IMPROVEMENT[1]} %"])
    return {
        "id": "calibrated-baseline",
        "title": "The paper's headline at its own baseline (`--calibrate-uvd-vx 5.7`)",
        **where_many(measured, "`pcuvd paper --part spiral --seed N [--doppler-estimator "
                               "kasai]`; the former defaults: with "
                               f"{options_text(FORMER_DEFAULTS)}"),
        "units": "calibrated noise level in dB; RMSE in mm/s (UVD = conventional + LS, PC-UVD = "
                 "coded + IRLS; the mean's PC-UVD Vx with its range over the seeds); "
                 "improvement in %",
        "columns": ["seed", "estimator, settings", "calibrated level", "UVD Vx / Vz",
                    "PC-UVD Vx / Vz", "improvement Vx / Vz"],
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
    """Every averaging kernel at the defaults' aperture and correction, then at the former
    defaults' (F# 1.5, uncorrected)."""
    rows, measured = [], []
    for options, name in ((DEFAULTS, "F# 1.0, corrected (the defaults' kernel: 5x1)"),
                          (FORMER_DEFAULTS, "F# 1.5, uncorrected (the former defaults)")):
        series = spiral_series(all_runs, options=options)
        if not series:
            continue
        measured += series
        rows += [[f"{name}, {seeds_text(seeds_of(series))}", *row]
                 for row in kernel_rows(series)]
    return {
        "id": "averaging-kernels",
        "title": "Spatial averaging of the autocorrelation",
        **where_many(measured, "`pcuvd paper --part spiral --seed N` (`--averaging-kernels`, "
                               "default 1x1,3x1,5x1,7x1,3x3); the former defaults: with "
                               f"{options_text(FORMER_DEFAULTS)}"),
        "units": "RMSE and resolution cost in mm/s (mean over the seeds, PC-UVD's Vx range in "
                 "brackets; the lowest PC-UVD Vx of each setting in bold); level in dB; "
                 "improvement in %",
        "columns": ["aperture, correction, seeds", "kernel (depth × lateral)", "extent",
                    "no noise, PC-UVD Vx / Vz", "calibrated level", "UVD Vz there",
                    "PC-UVD Vx / Vz there", "improvement Vx / Vz", "resolution cost Vx / Vz"],
        "rows": rows + [
            ["paper", "–", "–", "–", "–", f2(PAPER_UVD[1]), f"{f2(PAPER_PCUVD[0])} / "
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
    """The correction alone: F# 1.5 and pixel-wise, with and without it."""
    corrected = {**FORMER_DEFAULTS, "partial_volume": True}
    series = spiral_series(all_runs, options=corrected)
    if not series:
        return None
    rows = [correction_row(str(r["metrics"]["seed"]), [r]) for r in series]
    rows.append(correction_row(f"**mean, {seeds_text(seeds_of(series))}**", series))
    plain = spiral_series(all_runs, options=FORMER_DEFAULTS)
    rows.append(correction_row(f"without the correction (mean, {seeds_text(seeds_of(plain))})", plain))
    rows.append(["paper", "–", f"{f2(PAPER_UVD[0])} / {f2(PAPER_UVD[1])}",
                 f"{f2(PAPER_PCUVD[0])} / {f2(PAPER_PCUVD[1])}",
                 f"{PAPER_IMPROVEMENT[0]} / {PAPER_IMPROVEMENT[1]} %", "–", "–"])
    return {
        "id": "partial-volume",
        "title": f"The partial-volume correction alone (F# 1.5, pixel-wise), "
                 f"{seeds_text(seeds_of(series))}",
        **where_many(series, "`pcuvd paper --part spiral --partial-volume on|off --f-number 1.5 "
                             "--doppler-kernel 1x1 --seed N`"),
        "units": "calibrated level in dB; RMSE in mm/s (means give PC-UVD's Vx range over the "
                 "seeds); improvement in %",
        "columns": ["seed", *CORRECTION_COLUMNS],
        "rows": rows,
    }


def spiral_f_number(all_runs: list[dict]) -> dict | None:
    """The spiral at each receive f-number kept, pixel-wise with and without the correction,
    then the defaults."""
    cases = sorted({(r["metrics"]["f_number"], r["metrics"]["partial_volume"]) for r in all_runs
                    if r["metrics"]["doppler_estimator"] == "loupas"},
                   key=lambda c: (-c[0], c[1]))
    rows, measured = [], []
    for f_number, correction in cases:
        options = {"f_number": f_number, "partial_volume": correction, "doppler_kernel": [1, 1]}
        series = spiral_series(all_runs, options=options)
        if not series:
            continue
        measured += series
        label = (f_number_text(f_number)
                 + (" (the former default)" if options == FORMER_DEFAULTS else "")
                 + (", `--partial-volume on`" if correction else "")
                 + f" ({seeds_text(seeds_of(series))})")
        rows.append(correction_row(label, series))
    defaults = spiral_series(all_runs)
    if defaults:
        measured += defaults
        rows.append(correction_row(
            f"**{f_number_text(DEFAULTS['f_number'])}, `--partial-volume on`, "
            f"{kernel_name(DEFAULTS['doppler_kernel'])}: the defaults** "
            f"({seeds_text(seeds_of(defaults))})", defaults))
    if len(rows) < 2:  # nothing to compare the default aperture with
        return None
    return {
        "id": "spiral-f-number",
        "title": "The spiral at other receive apertures",
        **where_many(measured, "`pcuvd paper --part spiral --f-number F --partial-volume on|off "
                               "--doppler-kernel 1x1 --seed N`; the defaults: `pcuvd paper "
                               "--part spiral --seed N`"),
        "units": "calibrated level in dB (calibrated again at each aperture and with the "
                 "defaults' kernel); RMSE in mm/s (PC-UVD = coded + IRLS; means over the seeds, "
                 "PC-UVD's Vx range in brackets); improvement in %",
        "columns": ["F#", *CORRECTION_COLUMNS],
        "rows": rows,
    }


def kernel_correction(all_runs: list[dict]) -> dict | None:
    """Conventional UVD (LS) without noise through each kernel, at F# 1.0, with and without
    the correction: the averaging scores' floors of one seed."""
    pixel_wise = {"f_number": 1.0, "doppler_kernel": [1, 1]}
    plain = spiral_series(all_runs, options={**pixel_wise, "partial_volume": False})
    corrected = spiral_series(all_runs, options={**pixel_wise, "partial_volume": True})
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


def dealias_run(profile: str, noise_levels: int, all_runs: list[dict],
                options: dict | None = None, frames: int = 100) -> dict | None:
    """The dealiasing run with these processing options (default: the defaults) over several
    seeds for a tube profile: the one with the most seeds among those with at least
    `noise_levels` noise levels."""
    options = DEFAULTS if options is None else options

    def plain(r: dict) -> bool:
        s = r["metrics"]["dealias"]["settings"]
        return (s["tube_profile"] == profile and s["frames"] == frames
                and options_of(s) == options and len(s["noise_db"]) >= noise_levels)
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

    def label(frames: int, pv: bool, kernel: str) -> str:
        default = (pv, kernel) == (DEFAULTS["partial_volume"],
                                   kernel_name(DEFAULTS["doppler_kernel"]))
        return (f"{frames} frames, correction {'on' if pv else 'off'}, {kernel}"
                + (" (the defaults' at F# 1.0)" if default else ""))

    rows = [[label(frames, pv, kernel),
             *[cell(cells[(frames, pv, kernel)].get(f)) for f in apertures]]
            for frames, pv, kernel in sorted(cells)]
    commits = sorted({r["commit"] for r in measured})
    return {
        "id": "parabolic-tube-3x",
        "title": f"Parabolic tube at {multiple:g}× v_N without noise, conventional UVD (LS) "
                 f"dealiased: lumen within 10 % of the peak",
        "command": "`pcuvd paper --part dealias --dealias-noise-db off --f-number F --frames N "
                   "--partial-volume on|off --doppler-kernel K --dealias-seeds S` (the cell "
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
    """The accuracy targets, each scored from the kept runs at the defaults, beside the former
    defaults' and other settings' (or named with the test that asserts it)."""
    defaults = spiral_series(all_runs)
    former = spiral_series(all_runs, options=FORMER_DEFAULTS)
    plug = dealias_run("plug", 1, dealiasing)
    study = dealias_run("parabolic", 3, dealiasing)
    if not defaults or plug is None or study is None:
        return None
    longer_run = dealias_run("parabolic", 1, dealiasing, frames=400)
    longer_plug = dealias_run("plug", 1, dealiasing, frames=400)
    former_study = dealias_run("parabolic", 3, dealiasing, options=FORMER_DEFAULTS)
    former_plug = dealias_run("plug", 1, dealiasing, options=FORMER_DEFAULTS)
    finer_run = longer_study(dealiasing)

    def calibrated(series: list[dict], axis: str) -> list[float]:
        return [r["metrics"]["calibrated"]["rmse_mm_s"]["pcuvd_irls"][axis] for r in series]

    vz, vx = calibrated(defaults, "vz"), calibrated(defaults, "vx")
    seeds = seeds_text(seeds_of(defaults))
    plug3, parabolic3 = shares(plug, 3.0, None), shares(study, 3.0, None)
    noisy = [(n, shares(study, 3.0, n)) for n in sorted(
        {x["noise_db"] for x in study["metrics"]["dealias"]["rows"] if x["noise_db"] is not None})]
    slow = [x for x in study["metrics"]["dealias"]["rows"] if x["multiple"] == 1.0]
    untouched = all(x["unwrapped_lumen_pixels"] == 0 for x in slow)

    def verdict(values: list[float]) -> str:
        return f"{holds(bool(values) and min(values) >= 0.95)}: {share_text(values)}"

    def former_text(values: list[float]) -> str:
        return f"the former defaults ({options_text(FORMER_DEFAULTS)}): {value_range(values)}"

    tube_other = []
    if longer_run is not None:
        tube_other.append("parabolic, `--frames 400`, " + verdict(shares(longer_run, 3.0, None)))
    if longer_plug is not None:
        tube_other.append("plug flow, `--frames 400`, " + verdict(shares(longer_plug, 3.0, None)))
    if former_study is not None and former_plug is not None:
        tube_other.append("the former defaults: plug flow "
                          + share_text(shares(former_plug, 3.0, None)) + ", parabolic "
                          + share_text(shares(former_study, 3.0, None)))
    noisy_other = "–" if finer_run is None else (
        "parabolic, `--frames 400 --f-number 0.75 --partial-volume on --doppler-kernel 1x1`: "
        + "; ".join(f"{g_db(n)} {verdict(shares(finer_run, 3.0, n))}"
                    for n in sorted({x["noise_db"] for x in finer_run["metrics"]["dealias"]["rows"]
                                     if x["noise_db"] is not None})))
    rows = TESTED_TARGETS + [
        ["PC-UVD at the paper's baseline: Vz ≤ 1.59 mm/s",
         f"{holds(max(vz) <= 1.59)}: {value_range(vz)} ({seeds})",
         former_text(calibrated(former, "vz")) if former else "–"],
        ["PC-UVD at the paper's baseline: Vx ≤ 3.22 mm/s",
         f"{holds(max(vx) <= 3.22)}: {value_range(vx)}",
         former_text(calibrated(former, "vx")) if former else "–"],
        ["PC-UVD at the paper's baseline: Vx ≤ 2.5 mm/s (the aim)",
         f"{holds(max(vx) <= 2.5)}", "–"],
        ["dealiased tube at 3× v_N: ≥ 95 % of the lumen within 10 % of the peak, no noise",
         f"plug flow {verdict(plug3)}; parabolic {verdict(parabolic3)}",
         "; ".join(tube_other) or "–"],
        ["the same with noise: ≥ 95 %",
         "parabolic: " + "; ".join(f"{g_db(n)} {verdict(v)}" for n, v in noisy),
         noisy_other],
        ["dealiasing leaves slow flow (1× v_N) as it was",
         "holds (nothing unwrapped)" if untouched else "not met (pixels unwrapped at 1×)", "–"],
    ]
    brain = brain_runs()
    rows += brain_rows(brain)
    measured = (defaults + former + [plug, study]
                + [r for r in (longer_run, longer_plug, former_study, former_plug, finer_run)
                   if r is not None]
                + list(brain.values()))
    return {
        "id": "at-a-glance",
        "title": "The accuracy targets at a glance",
        "command": "per row: the named test (slow tier, every CI run); `pcuvd paper --part "
                   "spiral --seed N`; `pcuvd paper --part dealias --dealias-seeds ...` with the "
                   "options in the row; `pcuvd paper --part brain [--brain-svd-block-mm whole]` "
                   "(the [virtual rat brain](brain.md)'s runs); the former defaults: with "
                   f"{options_text(FORMER_DEFAULTS)}",
        "commit": ", ".join(sorted({r["commit"] for r in measured})),
        "cpu": "; ".join(sorted({r["cpu"] for r in measured})),
        "units": "RMSE in mm/s (ranges over the seeds); fractions of the lumen in %",
        "columns": ["target", "at the defaults", "with other settings"],
        "rows": rows,
    }


BRAIN = ROOT / "docs" / "results" / "metrics" / "brain"


def brain_runs() -> dict[str, dict]:
    """The brain's kept default run (`auto`: 2 mm clutter blocks) and its run with one clutter
    filter for the whole image, where kept."""
    return {name: json.loads((BRAIN / f"{name}.json").read_text())
            for name in ("auto", "blocks-whole") if (BRAIN / f"{name}.json").exists()}


def brain_rows(runs_: dict[str, dict]) -> list[list[str]]:
    """The virtual rat brain's targets, from its default run and its whole-image filter's run."""
    if "auto" not in runs_:
        return []
    default = runs_["auto"]["brain"]
    whole = runs_["blocks-whole"]["brain"] if "blocks-whole" in runs_ else None

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
        # The target's own group: the vessels at least a resolution cell (a wavelength) wide.
        wide_name = next(g["group"] for g in b["ri"] if g["group"].endswith("(a wavelength)"))
        wide = groups[wide_name]
        width = wide_name.removesuffix(" (a wavelength)")
        text = (f"{holds(wide['median_abs_error'] <= 0.05 and wide['class_accuracy'] >= 0.95)}"
                f": {wide['median_abs_error']:.2f}, {100 * wide['class_accuracy']:.0f} % "
                f"(PC-UVD, {width}, a resolution cell, as the target asks); "
                f"{every['median_abs_error']:.2f}, {100 * every['class_accuracy']:.0f} % "
                f"over every lumen pixel")
        if one:
            text += (f"; {one['median_abs_error']:.2f}, {100 * one['class_accuracy']:.0f} % where "
                     f"one class fills the elevation beam")
        return text

    return [
        ["virtual rat brain (`paper --part brain`): PC-UVD's vector RMSE ≥ 30 % below UVD's in "
         "the deepest third", deepest(default),
         "–" if whole is None else "`--brain-svd-block-mm whole`: " + deepest(whole)],
        ["virtual rat brain: median |ΔRI| ≤ 0.05, ≥ 95 % classed right", ri(default),
         "–" if whole is None else "`--brain-svd-block-mm whole`: " + ri(whole)],
    ]


def g_db(noise_db: float) -> str:
    """A noise level as the pages write it: `−10 dB`, `0 dB`, `+5 dB`."""
    return minus(f"{noise_db:+g} dB") if noise_db else "0 dB"
