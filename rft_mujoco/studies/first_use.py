"""First use and the warm demo, measured as a user meets them (``python -m rft_mujoco.studies.first_use``).

Builds a wheel of this checkout, installs it (``--no-deps``) into a new venv whose dependencies come from
the running environment (a ``.pth`` file), and times, from an empty folder:

1. ``cold``: ``python -m rft_mujoco demo --no-video`` with an empty numba cache (``RFT_MUJOCO_CACHE_DIR``
   set to a new folder): the very first use on a machine, compile included;
2. ``new install``: the same in the new venv with the user's cache (the default one, filled by any
   earlier install of the same sources and versions);
3. ``warm demo``: ``python -m rft_mujoco demo`` with its video, in the running environment.

Prints a table of wall seconds. Needs ``pip`` and the ``studies`` extra; writes only in a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import site
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _timed(cmd: list[str], cwd: Path, env: dict | None = None) -> tuple[float, str]:
    start = time.perf_counter()
    result = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({result.returncode}):\n{result.stdout[-2000:]}{result.stderr[-2000:]}")
    return seconds, result.stdout + result.stderr


def _fresh_venv(tmp: Path) -> Path:
    """A new venv with this checkout's wheel installed and the running environment's packages visible."""
    wheels = tmp / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(ROOT)], check=True)
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    Path(purelib, "running_env.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", str(next(wheels.glob("*.whl")))],
                   check=True)
    return python


def main(argv: list[str] | None = None, command: str = "first_use") -> int:
    parser = argparse.ArgumentParser(prog="python -m rft_mujoco.studies.first_use", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--skip-cold", action="store_true", help="skip the run with an empty numba cache")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rft_first_use_") as name:
        tmp = Path(name)
        work = tmp / "work"
        work.mkdir()
        python = _fresh_venv(tmp)
        demo = [str(python), "-m", "rft_mujoco", "demo", "--no-video", "--out", str(tmp / "out")]
        if not args.skip_cold:
            env = {**os.environ, "RFT_MUJOCO_CACHE_DIR": str(tmp / "empty_cache")}
            rows.append(("cold: new venv, empty numba cache, demo --no-video", *_timed(demo, work, env)))
        rows.append(("new install: new venv, the user's cache, demo --no-video", *_timed(demo, work)))
        warm = [sys.executable, "-m", "rft_mujoco", "demo", "--out", str(tmp / "warm")]
        _timed(warm, work)                                 # fills this environment's cache if needed
        rows.append(("warm demo with video (make demo without set-up)", *_timed(warm, work)))
    width = max(len(r[0]) for r in rows)
    print(f"{'case':<{width}}  wall s")
    for label, seconds, _ in rows:
        print(f"{label:<{width}}  {seconds:6.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
