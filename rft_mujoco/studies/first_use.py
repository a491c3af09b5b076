"""First use and the warm demo, measured as a user meets them (``python -m rft_mujoco.studies.first_use``).

Builds a wheel of this checkout, installs it (``--no-deps``) into a new venv whose dependencies come from
the running environment (a ``.pth`` file), and times, from an empty folder:

1. ``cold``: ``python -m rft_mujoco demo --no-video`` with an empty numba cache (``RFT_MUJOCO_CACHE_DIR``
   set to a new folder), the shipped machine code ignored: the very first use on a machine, compile
   included; in one process (``RFT_MUJOCO_COMPILE_PROCESSES=1``) and with phase 2 in a second process;
2. ``shipped`` (``--ship``): the same from a wheel built after ``python -m rft_mujoco compile --ship`` (in a
   copy of the checkout): the machine code comes with the wheel;
3. ``new install``: the same in the new venv with the user's cache (the default one, filled by any
   earlier install of the same sources and versions);
4. ``warm demo``: ``python -m rft_mujoco demo`` with its video, in the running environment.

Prints a table of wall seconds and CPU seconds (user + sys, the demo's processes together). Needs ``pip``
and the ``studies`` extra; writes only in a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import site
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _timed(cmd: list[str], cwd: Path, env: dict | None = None) -> tuple[float, float, str]:
    """(wall s, CPU s of the command and its children, output)."""
    cpu = _cpu()
    start = time.perf_counter()
    result = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({result.returncode}):\n{result.stdout[-2000:]}{result.stderr[-2000:]}")
    return seconds, _cpu() - cpu, result.stdout + result.stderr


def _shipping_copy(tmp: Path) -> Path:
    """A copy of the checkout (its package and build files) with ``compile --ship`` run in it."""
    copy = tmp / "ship_src"
    shutil.copytree(ROOT, copy, ignore=shutil.ignore_patterns(".venv", ".git", "out", "runs", "build", "__pycache__",
                                                              "*.egg-info", "machine_code"))
    env = {**os.environ, "PYTHONPATH": str(copy), "RFT_MUJOCO_CACHE_DIR": str(tmp / "ship_cache")}
    subprocess.run([sys.executable, "-m", "rft_mujoco", "compile", "--ship"], cwd=copy, env=env, check=True)
    return copy


def _fresh_venv(tmp: Path, source: Path = ROOT, name: str = "venv") -> Path:
    """A new venv with the wheel of ``source`` installed and the running environment's packages visible."""
    wheels = tmp / f"wheels_{name}"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(source)],
                   check=True)
    venv = tmp / name
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    Path(purelib, "running_env.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--ignore-installed",  # the running
                    str(next(wheels.glob("*.whl")))], check=True)         # environment's (editable) copy is seen
    return python


def main(argv: list[str] | None = None, command: str = "first_use") -> int:
    parser = argparse.ArgumentParser(prog="python -m rft_mujoco.studies.first_use", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--skip-cold", action="store_true", help="skip the runs with an empty numba cache")
    parser.add_argument("--ship", action="store_true", help="also time a wheel with shipped machine code (one "
                        "more full compile to build it)")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rft_first_use_") as name:
        tmp = Path(name)
        work = tmp / "work"
        work.mkdir()
        python = _fresh_venv(tmp)
        demo = ["-m", "rft_mujoco", "demo", "--no-video", "--out", str(tmp / "out"), "--overwrite"]
        clean = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}    # the venv's own rft_mujoco
        if not args.skip_cold:
            for label, processes in (("cold, one process: new venv, empty numba cache, demo --no-video", "1"),
                                     ("cold, two processes: the same, phase 2 compiled beside", "")):
                env = {**clean, "RFT_MUJOCO_CACHE_DIR": str(tmp / f"empty_cache{processes}"),
                       "RFT_MUJOCO_NO_SHIPPED_CODE": "1", "RFT_MUJOCO_COMPILE_PROCESSES": processes}
                rows.append((label, *_timed([str(python), *demo], work, env)))
        if args.ship:
            shipped = _fresh_venv(tmp, _shipping_copy(tmp), "venv_shipped")
            env = {**clean, "RFT_MUJOCO_CACHE_DIR": str(tmp / "empty_cache_shipped")}
            rows.append(("shipped: wheel built after compile --ship, new venv, empty numba cache",
                         *_timed([str(shipped), *demo], work, env)))
        rows.append(("new install: new venv, the user's cache, demo --no-video",
                     *_timed([str(python), *demo], work, clean)))
        warm = [sys.executable, "-m", "rft_mujoco", "demo", "--out", str(tmp / "warm"), "--overwrite"]
        _timed(warm, work)                                 # fills this environment's cache if needed
        rows.append(("warm demo with video (make demo without set-up)", *_timed(warm, work)))
    width = max(len(r[0]) for r in rows)
    print(f"{'case':<{width}}  wall s  CPU s")
    for label, seconds, cpu, _ in rows:
        print(f"{label:<{width}}  {seconds:6.1f}  {cpu:5.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
