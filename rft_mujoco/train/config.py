"""The run configuration: YAML hyperparameters keyed by env id, CLI overrides, and ``config.yaml``.

Resolution order, lowest to highest precedence (rl-zoo3's scheme):

1. the ``default`` entry of ``hyperparams/<algo>.yml`` (package data of ``rft_mujoco.train``,
   :data:`HYPERPARAMS_DIR`);
2. the entry named by the env id, which replaces default keys one by one (so an env's ``policy_kwargs``
   replaces the default's whole mapping); the shipped files are in rl-zoo3's format, where each env
   entry is already complete (``<<: *default``), so that rl-zoo3 reads the same hyperparameters;
3. ``--hyperparams key=value`` (or rl-zoo3's ``key:value``) overrides; dotted keys reach inside mappings
   (``policy_kwargs.net_arch=[64,64]``); values are parsed as YAML (``1e-3`` is a float);
4. the explicit flags ``--timesteps``, ``--n-envs`` and ``--env-kwargs key=value``.

Besides algorithm constructor arguments an entry may hold the experiment keys ``n_timesteps``,
``n_envs``, ``normalize`` (``true``/``false`` or a mapping of ``VecNormalize`` arguments) and
``env_kwargs`` (a mapping passed to ``gymnasium.make``), and rl-zoo3's ``callback`` (ignored here: our
trainer always logs the reward terms, :mod:`.callbacks`). ``policy_kwargs`` is a mapping or rl-zoo3's
string ``"dict(..., activation_fn=nn.ELU)"`` (read here without ``eval``: :func:`parse_policy_kwargs`);
``policy_kwargs.activation_fn`` is a name (``relu``, ``nn.ReLU``, ...) and ``learning_rate``/``clip_range``
may be ``lin_<value>`` for a linear decay to zero, so that every entry stays plain YAML.

The resolved :class:`RunConfig` is saved as ``config.yaml`` in the run directory; it is the only input
``evaluate`` needs to rebuild the env and reload the model.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime
import platform
import re
import shlex
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import yaml

ALGOS = ("ppo", "sac")
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
"""The shipped hyperparameter YAMLs (``<algo>.yml``), package data beside this module."""
DEFAULT_PROG = "python -m rft_mujoco.train"
DEFAULT_ENTRY = "default"
CONFIG_FILENAME = "config.yaml"
MODEL_FILENAME = "model.zip"
VECNORMALIZE_FILENAME = "vecnormalize.pkl"
VEC_ENVS = ("dummy", "subproc")
# keys of a hyperparameter entry that configure the experiment, not the algorithm constructor
EXPERIMENT_KEYS = ("n_timesteps", "n_envs", "normalize", "env_kwargs", "callback")
# VecNormalize arguments written out in full into config.yaml (gamma defaults to the algorithm's gamma)
NORMALIZE_DEFAULTS = {"norm_obs": True, "norm_reward": True, "clip_obs": 10.0, "clip_reward": 10.0,
                      "epsilon": 1e-8}
NORMALIZE_KEYS = (*NORMALIZE_DEFAULTS, "gamma", "norm_obs_keys")
ACTIVATIONS = {"relu": "ReLU", "tanh": "Tanh", "elu": "ELU", "leaky_relu": "LeakyReLU",
               "gelu": "GELU", "silu": "SiLU"}
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
VERSION_PACKAGES = ("rft_mujoco", "stable_baselines3", "gymnasium", "torch", "numpy", "mujoco")


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e-3`` and ``1e6`` as floats (YAML 1.1 wants ``1.0e-3``)."""


class _Dumper(yaml.SafeDumper):
    """SafeDumper that quotes strings such as ``"1e-3"`` which :class:`_Loader` would read as floats."""


_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                       |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                       |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                       |[-+]?\.(?:inf|Inf|INF)
                       |\.(?:nan|NaN|NAN))$""", re.X)
for _cls in (_Loader, _Dumper):
    _cls.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))
del _cls


def load_yaml(text_or_path: str | Path) -> Any:
    """Parse YAML from a path (``Path``) or a string, reading ``1e-3`` as a float."""
    text = Path(text_or_path).read_text() if isinstance(text_or_path, Path) else text_or_path
    return yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader subclass)


def check_algo(algo: str) -> str:
    """The lower-case algorithm name; ValueError naming the valid ones otherwise."""
    name = str(algo).lower()
    if name not in ALGOS:
        raise ValueError(f"algo must be one of {', '.join(ALGOS)}, got {algo!r}")
    return name


def algo_class(algo: str) -> type:
    """The stable-baselines3 class for ``algo`` (imports torch, so only when needed)."""
    import stable_baselines3

    return getattr(stable_baselines3, check_algo(algo).upper())


def parse_value(text: str) -> Any:
    """A CLI value as YAML: ``3`` -> 3, ``1e-3`` -> 0.001, ``[64,64]`` -> [64, 64], ``relu`` -> 'relu'."""
    try:
        return load_yaml(text)
    except yaml.YAMLError as err:
        raise ValueError(f"cannot parse value {text!r} as YAML: {err}") from None


_OVERRIDE = re.compile(r"^\s*([\w.]+)\s*[=:](.*)$", re.S)


def parse_overrides(items: Sequence[str], *, what: str = "--hyperparams") -> dict[str, Any]:
    """``["a=1", "b.c=[1,2]", "d:2"]`` -> ``{"a": 1, "b": {"c": [1, 2]}, "d": 2}`` (dotted keys nest;
    ``key:value`` is rl-zoo3's form)."""
    result: dict[str, Any] = {}
    for item in items:
        match = _OVERRIDE.match(item)
        if not match:
            raise ValueError(f"{what} entries must look like key=value, got {item!r} (rl-zoo3's key:value works too)")
        key, value = match.groups()
        *parents, leaf = key.strip().split(".")
        node = result
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"{what}: {key!r} sets a key inside a value that is not a mapping")
        node[leaf] = parse_value(value)
    return result


def parse_policy_kwargs(text: str) -> dict[str, Any]:
    """rl-zoo3's ``policy_kwargs`` string, e.g. ``"dict(log_std_init=-1.0, activation_fn=nn.ELU,
    net_arch=dict(pi=[256, 256], vf=[256, 256]))"``, as a plain mapping (``nn.ELU`` -> ``"nn.ELU"``), read
    with :mod:`ast` (literals, ``dict(...)`` and ``nn.<name>`` only; no ``eval``)."""
    import ast

    def value(node):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
            return {kw.arg: value(kw.value) for kw in node.keywords}
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "nn":
            return f"nn.{node.attr}"
        if isinstance(node, ast.Dict):
            return {value(k): value(v) for k, v in zip(node.keys, node.values)}
        if isinstance(node, (ast.List, ast.Tuple)):
            return [value(v) for v in node.elts]
        return ast.literal_eval(node)

    try:
        parsed = value(ast.parse(text.strip(), mode="eval").body)
    except (SyntaxError, ValueError) as err:
        raise ValueError(f"policy_kwargs {text!r}: expected a mapping or rl-zoo3's 'dict(key=value, ...)' with "
                         f"literals and nn.<Activation> ({err})") from None
    if not isinstance(parsed, dict):
        raise ValueError(f"policy_kwargs must be a mapping or 'dict(...)', got {text!r}")
    return parsed


def deep_update(base: Mapping[str, Any], updates: Mapping[str, Any]) -> dict[str, Any]:
    """A new dict: ``base`` with ``updates`` merged in recursively (mappings merge, others replace)."""
    merged = copy.deepcopy(dict(base))
    for key, value in updates.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_update(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def hyperparams_path(algo: str, path: str | Path | None = None) -> Path:
    """``path`` if given, else the shipped ``hyperparams/<algo>.yml`` (:data:`HYPERPARAMS_DIR`)."""
    return Path(path) if path is not None else HYPERPARAMS_DIR / f"{check_algo(algo)}.yml"


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> tuple[dict, list[str]]:
    """The ``default`` entry updated key by key with the ``env_id`` entry, and the entries used."""
    file = hyperparams_path(algo, path)
    if not file.is_file():
        raise FileNotFoundError(f"no hyperparameter file {file} for algo {algo!r}")
    table = load_yaml(file) or {}
    if not isinstance(table, dict) or DEFAULT_ENTRY not in table:
        raise ValueError(f"{file} must be a mapping of env id -> hyperparameters with a "
                         f"{DEFAULT_ENTRY!r} entry, got keys {sorted(table) if isinstance(table, dict) else table!r}")
    entries = [DEFAULT_ENTRY] + ([env_id] if env_id in table else [])
    merged: dict[str, Any] = {}
    for name in entries:
        entry = table[name] or {}
        if not isinstance(entry, dict):
            raise ValueError(f"{file}: entry {name!r} must be a mapping, got {entry!r}")
        merged.update(copy.deepcopy(entry))
    if isinstance(merged.get("policy_kwargs"), str):
        merged["policy_kwargs"] = parse_policy_kwargs(merged["policy_kwargs"])
    return merged, entries


def package_versions() -> dict[str, str]:
    """Python and the versions of the packages that decide a run's result."""
    versions = {"python": platform.python_version()}
    for name in VERSION_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything a run was made from; saved as ``config.yaml`` and reloaded by ``evaluate``.

    Attributes:
        algo: ``"ppo"`` or ``"sac"``.
        env_id: gymnasium id, e.g. ``"rft_mujoco/SandSwimmer-v0"``.
        seed: seed of the model and of env rank ``i`` (``seed + i``).
        n_envs: number of training envs.
        n_timesteps: total environment steps over all envs.
        env_kwargs: keyword arguments of ``gymnasium.make``.
        hyperparams: algorithm constructor arguments as plain YAML values (``policy`` included).
        normalize: ``VecNormalize`` arguments in full, or None when the run does not normalize.
        vec_env: ``"dummy"`` (one process) or ``"subproc"``.
        save_freq: checkpoint every this many total steps (0: no checkpoints).
        device: torch device (``"auto"``, ``"cpu"``, ``"cuda"``).
        num_threads: torch CPU threads (``torch.set_num_threads``); 0 keeps torch's default. One thread
            is the fastest for the small MLPs here (several threads contend with the env stepping).
        hyperparams_file: YAML file the hyperparameters came from (a shipped one as
            ``rft_mujoco/train/hyperparams/<algo>.yml``, no machine path).
        hyperparams_entries: its entries used, in order (``["default", env_id]`` or ``["default"]``).
        overrides: the ``--hyperparams`` and ``--env-kwargs`` items as given.
        versions: python and package versions.
        command: the command line.
        created: local time the run was configured, ISO 8601.
    """

    algo: str
    env_id: str
    seed: int
    n_envs: int
    n_timesteps: int
    env_kwargs: dict
    hyperparams: dict
    normalize: dict | None
    vec_env: str
    save_freq: int
    device: str
    num_threads: int
    hyperparams_file: str
    hyperparams_entries: list
    overrides: list
    versions: dict
    command: str
    created: str

    def run_name(self) -> str:
        """``<env>_<algo>_<seed>_<timestamp>`` with ``/`` in the env id written as ``-``."""
        stamp = datetime.datetime.fromisoformat(self.created).strftime("%Y%m%d-%H%M%S")
        return f"{self.env_id.replace('/', '-').replace(':', '-')}_{self.algo}_{self.seed}_{stamp}"


def _positive_int(name: str, value: Any) -> int:
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not number >= 1 or number != int(number):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(number)


def _resolve_normalize(value: Any, hyperparams: Mapping[str, Any]) -> dict | None:
    if value is None or value is False:
        return None
    if value is True:
        value = {}
    if not isinstance(value, Mapping):
        raise ValueError(f"normalize must be true, false or a mapping of VecNormalize arguments, got {value!r}")
    unknown = sorted(set(value) - set(NORMALIZE_KEYS))
    if unknown:
        raise ValueError(f"normalize: unknown VecNormalize arguments {unknown}; valid: {list(NORMALIZE_KEYS)}")
    # like rl-zoo3: the return normalization discounts with the algorithm's gamma
    return {**NORMALIZE_DEFAULTS, "gamma": float(hyperparams.get("gamma", 0.99)), **value}


def resolve_config(
    *,
    algo: str,
    env_id: str,
    seed: int = 0,
    timesteps: int | None = None,
    n_envs: int | None = None,
    hyperparams: Sequence[str] = (),
    env_kwargs: Sequence[str] = (),
    hyperparams_file: str | Path | None = None,
    vec_env: str = "dummy",
    save_freq: int = 100_000,
    device: str = "auto",
    num_threads: int = 1,
    command: str | None = None,
) -> RunConfig:
    """Resolve YAML entries and CLI overrides (``key=value`` strings) into a :class:`RunConfig`.

    Does not check that ``env_id`` is registered (see :func:`.environments.check_env_id`).
    """
    algo = check_algo(algo)
    if vec_env not in VEC_ENVS:
        raise ValueError(f"vec_env must be one of {', '.join(VEC_ENVS)}, got {vec_env!r}")
    if int(num_threads) < 0:
        raise ValueError(f"num_threads must be >= 0 (0: torch's default), got {num_threads!r}")
    if int(save_freq) < 0:
        raise ValueError(f"save_freq must be >= 0 (0: no checkpoints), got {save_freq!r}")
    file = hyperparams_path(algo, hyperparams_file)
    merged, entries = load_hyperparams(algo, env_id, file)
    merged = deep_update(merged, parse_overrides(hyperparams))
    if isinstance(merged.get("policy_kwargs"), str):
        merged["policy_kwargs"] = parse_policy_kwargs(merged["policy_kwargs"])
    n_timesteps = timesteps if timesteps is not None else merged.get("n_timesteps")
    if n_timesteps is None:
        raise ValueError(f"no n_timesteps in {file} entries {entries}: pass --timesteps")
    env_kw = merged.get("env_kwargs") or {}
    if not isinstance(env_kw, Mapping):
        raise ValueError(f"env_kwargs must be a mapping, got {env_kw!r}")
    env_kw = deep_update(env_kw, parse_overrides(env_kwargs, what="--env-kwargs"))
    algo_params = {k: v for k, v in merged.items() if k not in EXPERIMENT_KEYS}
    algo_params.setdefault("policy", "MlpPolicy")
    return RunConfig(
        algo=algo,
        env_id=str(env_id),
        seed=int(seed),
        n_envs=_positive_int("n_envs", n_envs if n_envs is not None else merged.get("n_envs", 1)),
        n_timesteps=_positive_int("n_timesteps", n_timesteps),
        env_kwargs=dict(env_kw),
        hyperparams=algo_params,
        normalize=_resolve_normalize(merged.get("normalize", False), algo_params),
        vec_env=vec_env,
        save_freq=int(save_freq),
        device=str(device),
        num_threads=int(num_threads),
        hyperparams_file=_shown_path(file),
        hyperparams_entries=entries,
        overrides=[f"--hyperparams {item}" for item in hyperparams]
        + [f"--env-kwargs {item}" for item in env_kwargs],
        versions=package_versions(),
        command=command if command is not None else "",
        created=datetime.datetime.now().isoformat(timespec="seconds"),
    )


def _shown_path(file: Path) -> str:
    """``file`` as recorded in ``config.yaml``: a shipped YAML relative to the package's parent folder."""
    try:
        return str(Path("rft_mujoco", "train", "hyperparams") / file.resolve().relative_to(HYPERPARAMS_DIR))
    except ValueError:
        return str(file)


def command_line(argv: Sequence[str], prog: str = DEFAULT_PROG) -> str:
    """``prog`` (``python -m rft_mujoco.train``) followed by ``argv``, shell-quoted."""
    return shlex.join([*shlex.split(prog), *argv])


def save_config(config: RunConfig, run_dir: str | Path, prog: str = DEFAULT_PROG) -> Path:
    """Write ``run_dir/config.yaml``; returns its path."""
    path = Path(run_dir) / CONFIG_FILENAME
    path.parent.mkdir(parents=True, exist_ok=True)
    header = (f"# Resolved configuration of this run ({config.command or prog}).\n"
              f"# Rebuild and evaluate with: {prog} evaluate --run {Path(run_dir)}\n")
    path.write_text(header + yaml.dump(dataclasses.asdict(config), Dumper=_Dumper, sort_keys=False,
                                          default_flow_style=None, width=100))
    return path


def load_config(path: str | Path) -> RunConfig:
    """Read a :class:`RunConfig` from ``config.yaml`` or from the run directory holding it."""
    path = Path(path)
    if path.is_dir():
        path = path / CONFIG_FILENAME
    if not path.is_file():
        raise FileNotFoundError(f"no {CONFIG_FILENAME} at {path}: pass a run directory written by "
                                f"`{DEFAULT_PROG} train` (runs/<env>_<algo>_<seed>_<timestamp>)")
    data = load_yaml(path)
    fields = [f.name for f in dataclasses.fields(RunConfig)]
    if not isinstance(data, dict):
        raise ValueError(f"{path} must hold a mapping, got {type(data).__name__}")
    missing = [name for name in fields if name not in data]
    unknown = sorted(set(data) - set(fields))
    if missing or unknown:
        raise ValueError(f"{path} does not match RunConfig: missing keys {missing}, unknown keys {unknown}")
    return RunConfig(**data)


def set_num_threads(config: RunConfig) -> None:
    """Apply ``config.num_threads`` to torch (0: leave torch's default)."""
    if config.num_threads > 0:
        import torch

        torch.set_num_threads(config.num_threads)


def algo_kwargs(config: RunConfig) -> dict[str, Any]:
    """Constructor arguments of the algorithm: activation names -> torch classes, ``lin_x`` -> schedules."""
    from stable_baselines3.common.utils import LinearSchedule
    from torch import nn

    kwargs = copy.deepcopy(config.hyperparams)
    for key in SCHEDULE_KEYS:
        value = kwargs.get(key)
        if isinstance(value, str) and value.startswith("lin_"):
            try:
                kwargs[key] = LinearSchedule(float(value[4:]), 0.0, 1.0)
            except ValueError:
                raise ValueError(f"{key} must be a number or lin_<number>, got {value!r}") from None
    policy_kwargs = kwargs.get("policy_kwargs")
    if isinstance(policy_kwargs, dict) and isinstance(policy_kwargs.get("activation_fn"), str):
        name = policy_kwargs["activation_fn"]
        class_name = ACTIVATIONS.get(name.lower(), name.removeprefix("nn."))
        if not isinstance(getattr(nn, class_name, None), type):
            raise ValueError(f"policy_kwargs.activation_fn must be one of {sorted(ACTIVATIONS)} "
                             f"(or a torch.nn class name), got {name!r}")
        policy_kwargs["activation_fn"] = getattr(nn, class_name)
    return kwargs
