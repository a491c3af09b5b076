"""Learning curves (episode return vs environment steps) from the Monitor CSVs of training runs.

``python -m rft_mujoco.train plot RUN_DIR [RUN_DIR ...] --out curve.png``. Each run's ``monitor/*.monitor.csv``
files (one per training env) are merged in wall-clock order and the episode lengths summed to give the
step count at each episode end, as stable-baselines3's ``results_plotter`` does (without pandas).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

MONITOR_GLOB = "*monitor.csv"


def monitor_files(path: str | Path) -> list[Path]:
    """Monitor CSVs of a run directory (its ``monitor/`` folder, with the ``resumed_<steps>/`` folders of
    resumed runs), of a folder and its subfolders, or the file itself."""
    path = Path(path)
    if path.is_file():
        return [path]
    folder = path / "monitor" if (path / "monitor").is_dir() else path
    return sorted(folder.rglob(MONITOR_GLOB))


def load_monitor(path: str | Path) -> dict[str, np.ndarray]:
    """Episodes of a run, ordered by end time.

    Returns ``{"timesteps": (n,) int, "returns": (n,) float, "lengths": (n,) int, "time_s": (n,) float}``
    where ``timesteps`` is the total step count over all envs at each episode's end and ``time_s`` the
    wall time since the earliest env started. Empty arrays when no episode has finished.
    """
    rows, starts = [], []
    for file in monitor_files(path):
        with file.open() as handle:
            first = handle.readline()
            if not first.startswith("#"):
                raise ValueError(f"{file} is not a Monitor CSV: first line should be '#{{json}}', got {first!r}")
            t_start = float(json.loads(first[1:]).get("t_start", 0.0))
            starts.append(t_start)
            for row in csv.DictReader(handle):
                rows.append((t_start + float(row["t"]), float(row["r"]), int(float(row["l"]))))
    rows.sort()
    if not rows:
        return {"timesteps": np.zeros(0, int), "returns": np.zeros(0), "lengths": np.zeros(0, int),
                "time_s": np.zeros(0)}
    end, returns, lengths = (np.asarray(col) for col in zip(*rows))
    return {"timesteps": np.cumsum(lengths), "returns": returns.astype(float),
            "lengths": lengths.astype(int), "time_s": end - min(starts)}


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """(n,) -> (n,): mean of the last ``min(window, i + 1)`` values at each index ``i``."""
    values = np.asarray(values, dtype=float)
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    cumsum = np.concatenate([[0.0], np.cumsum(values)])
    idx = np.arange(1, values.size + 1)
    lo = np.maximum(idx - window, 0)
    return (cumsum[idx] - cumsum[lo]) / (idx - lo)


def plot_learning_curves(ax, runs: Sequence[str | Path], *, window: int = 10) -> int:
    """Draw each run's episode returns (faint) and their moving average on ``ax``; returns curves drawn."""
    drawn = 0
    for run in runs:
        data = load_monitor(run)
        if data["returns"].size == 0:
            continue
        name = Path(run).name if Path(run).name != "monitor" else Path(run).parent.name
        line, = ax.plot(data["timesteps"], moving_average(data["returns"], window), label=name)
        ax.plot(data["timesteps"], data["returns"], color=line.get_color(), alpha=0.25, lw=0.8)
        drawn += 1
    ax.set_xlabel("environment steps")
    ax.set_ylabel(f"episode return (moving average of {window})")
    ax.set_title("learning curve")
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize="small")
    return drawn


def plot(runs: Sequence[str | Path], out: str | Path, *, window: int = 10) -> Path:
    """Save the learning curves of ``runs`` to ``out``; ValueError when no run has a finished episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    try:
        if plot_learning_curves(ax, runs, window=window) == 0:
            raise ValueError(f"no finished episodes in the Monitor CSVs of {[str(r) for r in runs]} "
                             f"(looked for {MONITOR_GLOB} in each run's monitor/ folder)")
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.tight_layout()
        fig.savefig(out, dpi=120)
    finally:
        plt.close(fig)
    return out
