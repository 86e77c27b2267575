"""The README's Python examples run as written (one per function family)."""

from __future__ import annotations

import os
import re

import pytest

from conftest import REPO


def _python_examples() -> list[str]:
    text = (REPO / "README.md").read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_the_readme_has_examples():
    assert len(_python_examples()) >= 3


@pytest.mark.parametrize("index", range(3))
def test_readme_example_runs(index, disk, tmp_path, monkeypatch):
    code = _python_examples()[index].replace("../shared/data/PWI_disk.mat", os.fspath(disk))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"README.md python example {index + 1}", "exec"), {})
