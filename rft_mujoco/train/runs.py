"""Where runs are: a run folder, or a shipped run found by its name; where their outputs go.

``find_run("SandQuadruped-v1")`` is the shipped policy (``rft_mujoco/train/pretrained/SandQuadruped-v1``,
package data) unless a folder of that name (holding ``config.yaml``) exists where it is looked up: a folder
always wins, so a user's own run is never shadowed by a shipped one. Outputs never go into a run folder
(a shipped one lives inside the installed package): :func:`default_out` is ``./out/<command>/<run name>``,
and :func:`check_free` refuses to overwrite files that already exist unless asked to.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from .config import CONFIG_FILENAME

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"
"""The shipped runs (package data): one folder per run, named by what it is (``SandQuadruped-v1``)."""

OUT_DIR = Path("out")
"""Default parent folder of every output, relative to the working directory."""


def shipped_runs() -> list[str]:
    """Names of the shipped runs, sorted (``["SandQuadruped-v1", "SandQuadruped-v1-rigid"]``)."""
    if not PRETRAINED_DIR.is_dir():
        return []
    return sorted(p.name for p in PRETRAINED_DIR.iterdir() if (p / CONFIG_FILENAME).is_file())


def find_run(run: str | Path) -> Path:
    """The run folder of ``run``: a folder holding ``config.yaml``, else the shipped run of that name.

    Raises FileNotFoundError naming what was looked for and the shipped names."""
    path = Path(run)
    if (path / CONFIG_FILENAME).is_file():
        return path
    if path.is_file() and path.name == CONFIG_FILENAME:
        return path.parent
    shipped = PRETRAINED_DIR / str(run)
    if len(path.parts) == 1 and (shipped / CONFIG_FILENAME).is_file():
        return shipped
    where = "is not a folder" if not path.exists() else f"holds no {CONFIG_FILENAME}"
    raise FileNotFoundError(f"no run {str(run)!r}: {path} {where}, and no shipped run has that name; pass a run "
                            f"folder written by `python -m rft_mujoco.train train` (runs/<env>_<algo>_<seed>_<time>) "
                            f"or a shipped run: {', '.join(shipped_runs()) or 'none installed'}")


def is_shipped(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` is one of the shipped runs (inside the installed package)."""
    try:
        Path(run_dir).resolve().relative_to(PRETRAINED_DIR)
    except ValueError:
        return False
    return True


def default_out(command: str, run_dir: str | Path) -> Path:
    """``./out/<command>/<run folder name>``: the default output folder of ``command`` for a run."""
    return OUT_DIR / command / Path(run_dir).resolve().name


def check_free(paths: Iterable[str | Path], *, overwrite: bool, flag: str = "--overwrite") -> None:
    """FileExistsError when one of ``paths`` exists and ``overwrite`` is False."""
    existing = [str(p) for p in paths if Path(p).exists()]
    if existing and not overwrite:
        raise FileExistsError(f"would overwrite {', '.join(existing)}: pass {flag} to replace them, or choose "
                              "another output folder (--out)")
