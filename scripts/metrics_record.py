"""What the results scripts share: where a run was measured, its kept record, and the write-or-check
of the data files they generate (scripts/paper-results, scripts/brain-results,
scripts/speed-results import it from beside them).

Python 3, standard library only.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def commit_of(built_from: str = "HEAD") -> str:
    """The short commit `built_from` names in this repository."""
    return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", built_from],
                          capture_output=True, text=True, check=True).stdout.strip()


def this_cpu() -> str:
    """This machine's CPU model, core count and widest vector instructions, as the pages name it:
    instances of one model name differ (an AMD EPYC with or without AVX-512), and the
    beamformer's speed follows the vector width."""
    lines = Path("/proc/cpuinfo").read_text().splitlines()
    def field(name: str) -> str | None:
        return next((line.split(":", 1)[1].strip() for line in lines
                     if line.split(":", 1)[0].strip() == name), None)
    model = field("model name") or "unknown"
    # Virtual machines often report a generic name: the family and model tell generations apart.
    if field("cpu family") and field("model"):
        model += f", family {field('cpu family')} model {field('model')}"
    flags = next((line.split(":", 1)[1].split() for line in lines
                  if line.startswith("flags")), [])
    vectors = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else None
    return f"{model} ({os.cpu_count()} cores{', ' + vectors if vectors else ''})"


def json_text(value) -> str:
    """A data or metrics file's text: indented, UTF-8 as written, one final newline."""
    return json.dumps(value, indent=1, ensure_ascii=False) + "\n"


def without_timings(numbers: dict) -> dict:
    """A run's metrics.json without its timings (top level and each section's): they are the
    machine's, not the run's result, and speed.md measures them on purpose."""
    for part in [numbers, *numbers.values()]:
        if isinstance(part, dict):
            part.pop("timing_s", None)
            part.pop("total_s", None)
    return numbers


def keep(folder: Path, name: str, record: dict) -> None:
    """Writes `record` as folder/NAME.json (NAME may name a subfolder)."""
    path = folder / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json_text(record))


def replace_table(page: dict, table: dict, file_name: str) -> None:
    """Puts `table` in place of the one table of its id in `page`'s content."""
    blocks = [b for b in page["content"] if b.get("table", {}).get("id") == table["id"]]
    if len(blocks) != 1:
        raise SystemExit(f"{file_name}: expected one table `{table['id']}`, found {len(blocks)}")
    blocks[0]["table"] = table


def write_or_check(files: dict[Path, str], check: bool, script: str) -> int:
    """Writes each file's text, or with `check` writes nothing and returns 1 when one differs."""
    stale = []
    for path, text in files.items():
        if path.exists() and path.read_text() == text:
            continue
        if check:
            stale.append(str(path.relative_to(ROOT)))
        else:
            path.write_text(text)
            print(f"wrote {path.relative_to(ROOT)}")
    if stale:
        print(f"stale (run {script}):", ", ".join(stale), file=sys.stderr)
        return 1
    return 0
