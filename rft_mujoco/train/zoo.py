"""A run of ours in rl-zoo3's layout, so that ``python -m rl_zoo3.enjoy`` (and the zoo's other scripts)
load it: ``python -m rft_mujoco.train zoo --run RUN -f logs``.

rl-zoo3 2.9 finds an experiment by ``-f FOLDER --algo ALGO --env ID --exp-id N`` at
``FOLDER/ALGO/<env name>_N/``, where ``<env name>`` is the env id with ``/`` written as ``-`` (and only the
part after a ``module:`` prefix), :func:`zoo_env_name`. That folder holds::

    <env name>.zip                 the final model            <- our model.zip
    <env name>/config.yml          the hyperparameters        <- written from our config.yaml
    <env name>/args.yml            the command-line arguments <- written from our config.yaml
    <env name>/vecnormalize.pkl    VecNormalize statistics    <- our vecnormalize.pkl
    best_model.zip, evaluations.npz                           <- ours (runs trained with --eval-freq)
    rl_model_<steps>_steps.zip     checkpoints                <- our checkpoints/model_<steps>_steps.zip
    <rank>.monitor.csv             episode logs               <- our monitor/<rank>.monitor.csv

The model, statistics, checkpoints and logs of a run of yours are hard links to the run's files where
the file system allows it (no second copy of the model; a hard link is the same file, so whatever
writes into it in place writes into the run), else copies; those of a shipped run are copies (2 MB),
so that nothing done in the zoo's folder can alter the installed package. The
zoo's ``enjoy`` reads ``config.yml`` for ``normalize`` (and ``env_kwargs``) and ``args.yml`` for
``env_kwargs``; our env factory is the zoo's (``gymnasium.make`` of the id with its kwargs, a Monitor),
so the policy sees the observations it was trained on.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path
from typing import Any

import yaml

from .config import MODEL_FILENAME, VECNORMALIZE_FILENAME, RunConfig, load_config
from .experiment import CHECKPOINT_PREFIX
from .runs import find_run, is_shipped

ZOO_CHECKPOINT = "rl_model_{steps}_steps.zip"
"""rl-zoo3's checkpoint name (``enjoy --load-checkpoint STEPS``)."""


def zoo_env_name(env_id: str) -> str:
    """The env id as rl-zoo3 names its folders and files (huggingface_sb3's ``EnvironmentName``):
    ``rft_mujoco/SandQuadruped-v1`` -> ``rft_mujoco-SandQuadruped-v1``; ``module:Name-v0`` -> ``Name-v0``."""
    name = str(env_id).replace("/", "-")
    if name.count(":") > 1:
        raise ValueError(f"env id {env_id!r} has more than one ':'; rl-zoo3 accepts at most one (module:Name-vN)")
    return name.rpartition(":")[2]


def latest_exp_id(folder: str | Path, algo: str, env_id: str) -> int:
    """The largest ``N`` of ``folder/algo/<env name>_N`` (0 when there is none), as rl-zoo3 counts."""
    name = zoo_env_name(env_id)
    pattern = re.compile(rf"^{re.escape(name)}_(\d+)$")
    parent = Path(folder) / algo
    ids = [int(m.group(1)) for p in parent.glob(f"{name}_*") if p.is_dir() and (m := pattern.match(p.name))]
    return max(ids, default=0)


def _policy_kwargs_string(value: Any) -> str:
    """A plain mapping as rl-zoo3's ``dict(...)`` string (activation names -> ``nn.<Class>``); the inverse
    of :func:`.config.parse_policy_kwargs`."""
    from .config import ACTIVATIONS

    def text(v: Any, key: str | None = None) -> str:
        if isinstance(v, dict):
            return "dict(" + ", ".join(f"{k}={text(x, k)}" for k, x in v.items()) + ")"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(text(x) for x in v) + "]"
        if key == "activation_fn" and isinstance(v, str):
            return "nn." + ACTIVATIONS.get(v.lower(), v.removeprefix("nn."))
        return repr(v)

    if not isinstance(value, dict):
        raise ValueError(f"policy_kwargs must be a mapping, got {value!r}")
    return text(value)


def zoo_hyperparams(config: RunConfig) -> dict[str, Any]:
    """The ``config.yml`` rl-zoo3 writes for a run: the hyperparameter entry it trained with (constructor
    arguments, ``n_timesteps``, ``n_envs``, ``normalize``, ``env_kwargs``), keys sorted as the zoo sorts them."""
    entry = dict(config.hyperparams)
    if isinstance(entry.get("policy_kwargs"), dict):
        entry["policy_kwargs"] = _policy_kwargs_string(entry["policy_kwargs"])
    entry.update(n_timesteps=config.n_timesteps, n_envs=config.n_envs,
                 normalize=dict(config.normalize) if config.normalize is not None else False)
    if config.env_kwargs:
        entry["env_kwargs"] = dict(config.env_kwargs)
    return dict(sorted(entry.items()))


def zoo_args(config: RunConfig, conf_file: str | None = None) -> dict[str, Any]:
    """The ``args.yml`` rl-zoo3 writes (its command-line arguments, by its names) for what our run knows."""
    return dict(sorted({
        "algo": config.algo,
        "env": config.env_id,
        "env_kwargs": dict(config.env_kwargs) or None,
        "seed": config.seed,
        "n_timesteps": config.n_timesteps,
        "device": config.device,
        "num_threads": config.num_threads,
        "vec_env": config.vec_env,
        "save_freq": config.save_freq,
        "conf_file": conf_file or config.hyperparams_file,
        "hyperparams": [item.split(" ", 1)[1] for item in config.overrides if item.startswith("--hyperparams ")],
        "gym_packages": ["rft_mujoco.envs"] if config.env_id.startswith("rft_mujoco/") else [],
        "command": config.command,
    }.items()))


def _link_or_copy(src: Path, dst: Path, *, link: bool) -> str:
    """Hard-link ``src`` at ``dst`` when ``link`` (``"linked"``); copy it otherwise or where the file system
    refuses the link (``"copied"``)."""
    if link:
        try:
            os.link(src, dst)
            return "linked"
        except OSError:
            pass
    shutil.copy2(src, dst)
    return "copied"


def export_zoo(run: str | Path, folder: str | Path = "logs", *, exp_id: int | None = None,
               overwrite: bool = False) -> Path:
    """Write run ``run`` (a run folder or a shipped run name) as rl-zoo3 experiment
    ``folder/<algo>/<env name>_<exp_id>`` and return that folder: the run's files hard-linked (a shipped
    run's copied), ``config.yml`` and ``args.yml`` written (see the module docstring).

    ``exp_id`` defaults to the next free id (the zoo's own rule: largest + 1). An existing experiment
    folder is refused (FileExistsError) unless ``overwrite``; then it is replaced.
    """
    run_dir = find_run(run)
    config = load_config(run_dir)
    model = run_dir / MODEL_FILENAME
    if not model.is_file():
        raise FileNotFoundError(f"run {run_dir} has no {MODEL_FILENAME}: was its training interrupted before saving?")
    stats = run_dir / VECNORMALIZE_FILENAME
    if config.normalize is not None and not stats.is_file():
        raise FileNotFoundError(f"run {run_dir} normalizes observations but has no {VECNORMALIZE_FILENAME}")
    if exp_id is None:
        exp_id = latest_exp_id(folder, config.algo, config.env_id) + 1
    elif int(exp_id) < 1:
        raise ValueError(f"exp_id must be >= 1 (rl-zoo3's --exp-id of a run folder), got {exp_id!r}")
    name = zoo_env_name(config.env_id)
    exp = Path(folder) / config.algo / f"{name}_{int(exp_id)}"
    if exp.exists():
        if not overwrite:
            raise FileExistsError(f"{exp} exists: pass --overwrite to replace it, or another --exp-id")
        shutil.rmtree(exp)
    params = exp / name
    params.mkdir(parents=True)

    files = {model: exp / f"{name}.zip"}
    if config.normalize is not None:
        files[stats] = params / VECNORMALIZE_FILENAME
    for extra in ("best_model.zip", "evaluations.npz"):
        if (run_dir / extra).is_file():
            files[run_dir / extra] = exp / extra
    for ckpt in sorted((run_dir / "checkpoints").glob(f"{CHECKPOINT_PREFIX}_*_steps.zip")):
        steps = ckpt.name[len(CHECKPOINT_PREFIX) + 1:-len("_steps.zip")]
        if steps.isdigit():
            files[ckpt] = exp / ZOO_CHECKPOINT.format(steps=steps)
    for monitor in sorted((run_dir / "monitor").glob("*.monitor.csv")):
        files[monitor] = exp / monitor.name
    link = not is_shipped(run_dir)   # never a link into the installed package
    how = [_link_or_copy(src, dst, link=link) for src, dst in files.items()]

    dump = {"default_flow_style": False, "sort_keys": False}
    (params / "config.yml").write_text(yaml.safe_dump(zoo_hyperparams(config), **dump))
    (params / "args.yml").write_text(yaml.safe_dump(zoo_args(config), **dump))
    (params / "command.txt").write_text(config.command + "\n")
    print(f"wrote {exp} ({how.count('linked')} file(s) hard-linked, {how.count('copied')} copied from {run_dir})\n"
          f"enjoy with: python -m rl_zoo3.enjoy --algo {config.algo} --env {config.env_id}"
          f"{' --gym-packages rft_mujoco.envs' if config.env_id.startswith('rft_mujoco/') else ''}"
          f" -f {folder} --exp-id {int(exp_id)}", flush=True)
    return exp
