"""What the package ships and where its outputs go: shipped runs found by name from any directory, outputs
under ./out (never in a run folder), no overwrite without a flag, no machine paths in shipped files, LICENSE,
``--version``."""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import rft_mujoco

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(rft_mujoco.__file__).resolve().parent
MACHINE_PATH = re.compile(rb"(/work/|/home/|/Users/|/root/|/tmp/|[A-Z]:\\\\Users)")


def _shipped_files():
    for path in sorted(PACKAGE.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts and path.suffix not in (".pyc", ".nbi", ".nbc"):
            yield path


def test_no_machine_paths_in_shipped_files():
    """Every file of the package (sources, models, YAML, shipped runs, and the members of their zips)."""
    found = []
    for path in _shipped_files():
        blobs = [(path.name, path.read_bytes())]
        if path.suffix == ".zip":
            with zipfile.ZipFile(path) as z:
                blobs = [(f"{path.name}:{n}", z.read(n)) for n in z.namelist()]
        found += [f"{path.relative_to(PACKAGE)} ({name}): {m.group(0)!r}"
                  for name, blob in blobs for m in [MACHINE_PATH.search(blob)] if m]
    assert not found, found


def test_license_file_is_mit_and_packaged():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "WITHOUT WARRANTY OF ANY KIND" in text
    assert 'license-files = ["LICENSE"]' in (ROOT / "pyproject.toml").read_text()


def test_version_flag(tmp_path):
    result = subprocess.run([sys.executable, "-m", "rft_mujoco", "--version"], cwd=tmp_path, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"rft_mujoco {rft_mujoco.__version__} (mujoco ")


# --- shipped runs -------------------------------------------------------------------------------

pytest.importorskip("yaml")


def test_shipped_runs_are_found_by_name_and_a_folder_wins(tmp_path, monkeypatch):
    from rft_mujoco.train.runs import PRETRAINED_DIR, find_run, is_shipped, shipped_runs

    monkeypatch.chdir(tmp_path)
    assert shipped_runs() == ["SandQuadruped-v1", "SandQuadruped-v1-rigid"]
    found = find_run("SandQuadruped-v1")
    assert found == PRETRAINED_DIR / "SandQuadruped-v1" and is_shipped(found)
    own = tmp_path / "SandQuadruped-v1"                   # a user's own run of the same name wins
    own.mkdir()
    (own / "config.yaml").write_text("algo: ppo\n")
    assert find_run("SandQuadruped-v1") == Path("SandQuadruped-v1") and not is_shipped(own)
    with pytest.raises(FileNotFoundError, match="no run 'NoSuchRun'.*SandQuadruped-v1, SandQuadruped-v1-rigid"):
        find_run("NoSuchRun")
    with pytest.raises(FileNotFoundError, match="holds no config.yaml"):
        find_run(tmp_path)


def test_outputs_default_to_out_and_are_not_overwritten(tmp_path, monkeypatch):
    from rft_mujoco.train.runs import check_free, default_out, find_run

    monkeypatch.chdir(tmp_path)
    assert default_out("eval", find_run("SandQuadruped-v1")) == Path("out/eval/SandQuadruped-v1")
    target = tmp_path / "eval.json"
    check_free([target], overwrite=False)                 # nothing there yet
    target.write_text("{}")
    with pytest.raises(FileExistsError, match="would overwrite .*eval.json: pass --overwrite"):
        check_free([target], overwrite=False)
    check_free([target], overwrite=True)


def test_plot_of_a_shipped_run_by_name_writes_under_out(tmp_path, monkeypatch, capsys):
    """The CLI from an empty folder: the shipped run's learning curve goes to ./out/plot/, once."""
    pytest.importorskip("matplotlib")
    from rft_mujoco.train.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["plot", "SandQuadruped-v1"]) == 0
    assert (tmp_path / "out" / "plot" / "SandQuadruped-v1.png").is_file()
    with pytest.raises(SystemExit) as exit_info:
        main(["plot", "SandQuadruped-v1"])
    assert exit_info.value.code == 2 and "pass --overwrite" in capsys.readouterr().err
    assert main(["plot", "SandQuadruped-v1", "--overwrite"]) == 0
