"""The README's Python snippets run as written (from the repository root, as a user would paste them)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), flags=re.S)


def test_the_readme_has_python_snippets():
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize("k", range(len(BLOCKS)))
def test_readme_python_snippet_runs(k):
    (ROOT / "out").mkdir(exist_ok=True)  # the snippets write under out/, which .gitignore covers
    r = subprocess.run([sys.executable, "-c", BLOCKS[k]], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"README python block {k + 1} failed:\n{BLOCKS[k]}\n{r.stderr[-2000:]}"
