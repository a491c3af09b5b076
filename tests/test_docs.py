"""Every ``python`` code block in docs/ runs as written (as tests/test_readme.py does for the README)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parent.parent / "docs"
NEEDS = {"warp.md": "mujoco_warp"}
"""Optional packages a page's blocks need (the test skips without them)."""

BLOCKS = [pytest.param(page.name, i, code, id=f"{page.name}:{i}",
                       marks=[pytest.mark.slow] if page.name in NEEDS else [])   # warp compiles its kernels
          for page in sorted(DOCS.glob("*.md"))
          for i, code in enumerate(re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S))]


def test_docs_have_python_blocks():
    assert BLOCKS, "no ```python block found in docs/"


@pytest.mark.parametrize("page, index, code", BLOCKS)
def test_docs_python_block_runs_as_written(page, index, code, tmp_path):
    if page in NEEDS:
        pytest.importorskip(NEEDS[page])
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, f"{page} block {index}:\n{out.stderr[-3000:]}"
