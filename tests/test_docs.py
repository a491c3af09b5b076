"""Every ``python`` code block in docs/ runs as written (as tests/test_readme.py does for the README); every
``bash`` block runs as written where that is cheap, and the others (an hour of training, the whole
benchmark) are named here with the reason and checked without running them: their commands exist and our
own command lines parse."""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
       "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])}
"""The blocks run in an empty folder with this tree's package and this Python as ``python``."""
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
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                         env=ENV)
    assert out.returncode == 0, f"{page} block {index}:\n{out.stderr[-3000:]}"


BASH = {f"{page.name}:{i}": code for page in sorted(DOCS.glob("*.md"))
        for i, code in enumerate(re.findall(r"```bash\n(.*?)```", page.read_text(), flags=re.S))}

RUN = {
    "training.md:3": "the sand gap of the shipped runs: 12 episodes of 10 s (about 1 min on this 2-core VM)",
    "training.md:6": "a shipped run written in rl-zoo3's layout and one episode of it in rl_zoo3.enjoy (~20 s)",
}
"""The bash blocks run as written, and what they cost."""

NOT_RUN = {
    "deformable.md:0": "the box study, about a minute of CPU (tests/test_footprint.py runs it and asserts each "
                       "criterion)",
    "deformable.md:1": "three wheel passes three times, then five, a few minutes (tests/test_ruts.py runs the "
                       "default three)",
    "deformable.md:2": "the quadruped trotting 2.5 s, then flat and deformable side by side and once on numpy, a "
                       "minute (tests/test_deformable_coupling.py covers the surface in a task; the plot and frame "
                       "are in docs/)",
    "deformable.md:3": "the cost benchmark, flat and deformable side by side five times, numpy once, then one pair "
                       "per interval, about a minute (tests/test_deform_compiled.py runs both functions on short "
                       "trots)",
    "performance.md:0": "the whole benchmark, ~5 min (tests/test_bench.py runs it with --quick)",
    "training.md:0": "an hour of training (tests/test_train.py trains with the same command on a tiny budget)",
    "training.md:2": "the shipped policy evaluated under each solve, 10 episodes and the command table each, "
                     "about 10 minutes (tests/test_train.py evaluates a run with --env-kwargs solve=implicit)",
    "training.md:1": "10 episodes of 20 s per policy, the command table and a video, several minutes "
                     "(tests/test_train.py evaluates the shipped run on fewer episodes)",
    "training.md:4": "resumes a run of your own (tests/test_train.py interrupts a tiny run with SIGTERM and resumes "
                     "it by folder and by name)",
    "training.md:5": "a million steps of rl-zoo3 training (tests/test_zoo.py runs the zoo's train, evaluation and "
                     "enjoy with the same YAML on a tiny budget)",
}
"""The bash blocks not run, and why: their commands are checked (:func:`test_costly_bash_block_commands_exist`)."""


def test_every_bash_block_is_run_or_says_why_not():
    assert not set(RUN) & set(NOT_RUN)
    assert set(BASH) == set(RUN) | set(NOT_RUN), (
        f"bash blocks of docs/ to classify in tests/test_docs.py: {sorted(set(BASH) - set(RUN) - set(NOT_RUN))}; "
        f"gone: {sorted(set(RUN) | set(NOT_RUN) - set(BASH))}")


def _run_bash(code: str, cwd: Path, timeout: int = 900) -> str:
    out = subprocess.run(["bash", "-euo", "pipefail", "-c", code], cwd=cwd, capture_output=True, text=True,
                         timeout=timeout, env=ENV)
    assert out.returncode == 0, f"{code}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out.stdout


def _doc_gap_rows() -> dict[tuple[str, str], float]:
    """The forward speeds of docs/training.md's sand-gap table, by (trained on, evaluated on)."""
    rows = re.findall(r"^\| (sand|rigid) \| (sand|rigid) \| ([\d.]+) \|", (DOCS / "training.md").read_text(), re.M)
    return {(a, b): float(v) for a, b, v in rows}


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(RUN))
def test_bash_block_runs_as_written(key, tmp_path):
    pytest.importorskip("stable_baselines3")
    if "rl_zoo3" in BASH[key]:
        pytest.importorskip("rl_zoo3")
    out = _run_bash(BASH[key], tmp_path)
    if key == "training.md:3":   # the page's table is what the command prints
        printed = re.findall(r"^(sand|rigid)\s+(sand|rigid)\s+([\d.]+)\s", out, re.M)
        assert len(printed) == 4 and set(_doc_gap_rows()) == {(a, b) for a, b, _ in printed}, out
        for a, b, vx in printed:
            assert float(vx) == pytest.approx(_doc_gap_rows()[a, b], abs=0.005), (a, b, out)
    if key == "training.md:6":   # the shipped run replayed by the zoo, with its VecNormalize statistics
        assert "rft_mujoco-SandQuadruped-v1_1" in out and "Loading running average" in out, out
        assert "Mean episode length: 1000.00" in out, out


def _commands(code: str) -> list[list[str]]:
    """The ``python -m ...`` command lines of a block, split as the shell would (comments dropped)."""
    return [shlex.split(line, comments=True) for line in code.splitlines() if line.strip().startswith("python -m")]


@pytest.mark.parametrize("key", sorted(NOT_RUN))
def test_costly_bash_block_commands_exist(key, tmp_path):
    """Each command of a block not run: its module answers ``--help``, and our own training CLI parses the
    command line as written (its flags and values) and finds the runs it names."""
    if "rft_mujoco.train" in BASH[key] or "rl_zoo3" in BASH[key]:
        pytest.importorskip("stable_baselines3")
    if "rl_zoo3" in BASH[key]:
        pytest.importorskip("rl_zoo3")
    commands = _commands(BASH[key])
    assert commands, f"{key}: no python -m command"
    lines = [line.split(" #")[0].rstrip() for line in BASH[key].splitlines()]
    _run_bash("\n".join(line + " --help" if line.startswith("python -m") else line for line in lines), tmp_path)
    from rft_mujoco.train import cli, runs

    for argv in commands:
        if argv[2] == "rft_mujoco.train":
            args = cli._parser().parse_args(argv[3:])   # SystemExit (a failure) on a bad flag or value
            for name in ("run", "sand", "rigid"):
                if getattr(args, name, None):
                    runs.find_run(getattr(args, name))
