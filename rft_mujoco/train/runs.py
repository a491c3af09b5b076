"""Where runs are: a run folder, or a shipped run found by its name; where their outputs go.

``find_run("SandQuadruped-v1")`` is the shipped policy (``rft_mujoco/train/pretrained/SandQuadruped-v1``,
package data) unless a folder of that name (holding ``config.yaml``) exists where it is looked up: a folder
always wins, so a user's own run is never shadowed by a shipped one. Outputs never go into a run folder
(a shipped one lives inside the installed package): :func:`default_out` is ``./out/<command>/<run name>``,
and :func:`check_free` refuses to overwrite files that already exist unless asked to. What a run can be resumed
from: :func:`latest_checkpoint`.
"""

from __future__ import annotations

import dataclasses
import json
import re
import zipfile
from collections.abc import Iterable
from pathlib import Path

from .config import CONFIG_FILENAME, MODEL_FILENAME, VECNORMALIZE_FILENAME

CHECKPOINTS_DIR = "checkpoints"
CHECKPOINT_PREFIX = "model"
"""Checkpoints are ``checkpoints/model_<steps>_steps.zip`` (+ ``model_vecnormalize_<steps>_steps.pkl``,
``model_replay_buffer_<steps>_steps.pkl``): SB3's CheckpointCallback names with this prefix."""
_CHECKPOINT = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps\.zip$")

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


@dataclasses.dataclass(frozen=True)
class Checkpoint:
    """A saved state of a run: the model after ``steps`` total env steps and what was saved with it (None:
    not saved)."""

    steps: int
    model: Path
    vecnormalize: Path | None
    replay_buffer: Path | None

    def files(self) -> list[Path]:
        return [p for p in (self.model, self.vecnormalize, self.replay_buffer) if p is not None]


def checkpoint_paths(run_dir: str | Path, steps: int) -> Checkpoint:
    """The files of a checkpoint at ``steps`` (whether or not they exist)."""
    folder = Path(run_dir) / CHECKPOINTS_DIR
    return Checkpoint(int(steps), folder / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip",
                      folder / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl",
                      folder / f"{CHECKPOINT_PREFIX}_replay_buffer_{steps}_steps.pkl")


def model_steps(path: str | Path) -> int:
    """The total env steps (``num_timesteps``) an SB3 model file was saved at (read from its ``data`` entry)."""
    try:
        with zipfile.ZipFile(path) as archive:
            return int(json.loads(archive.read("data"))["num_timesteps"])
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path} is not a stable-baselines3 model file with num_timesteps ({exc})") from None


def latest_checkpoint(run_dir: str | Path) -> Checkpoint | None:
    """The latest saved state of a run: the checkpoint with the most steps in ``checkpoints/`` (periodic or
    saved when the run was interrupted), or ``model.zip`` when it has more steps (a run that finished); with
    its VecNormalize statistics and replay buffer where they exist. None when the run saved no model."""
    run_dir = Path(run_dir)
    found = None
    for file in (run_dir / CHECKPOINTS_DIR).glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"):
        match = _CHECKPOINT.match(file.name)
        if match and (found is None or int(match.group(1)) > found.steps):
            found = checkpoint_paths(run_dir, int(match.group(1)))
    if found is not None:
        found = dataclasses.replace(found, vecnormalize=found.vecnormalize if found.vecnormalize.is_file() else None,
                                    replay_buffer=found.replay_buffer if found.replay_buffer.is_file() else None)
    final = run_dir / MODEL_FILENAME
    if final.is_file():
        steps = model_steps(final)
        if found is None or steps > found.steps:
            stats = run_dir / VECNORMALIZE_FILENAME
            found = Checkpoint(steps, final, stats if stats.is_file() else None, None)
    return found
