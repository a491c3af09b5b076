"""rl-zoo3 reads our hyperparameter files and trains, evaluates (``--eval-freq``) and enjoys on our tasks;
the runs log the reward terms to TensorBoard; rl-zoo3's enjoy replays the runs of our front (and the shipped
ones) once ``python -m rft_mujoco.train zoo`` has written them in its layout. A tiny budget: the point is
the round trip, not learning."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")
pytest.importorskip("stable_baselines3")
pytest.importorskip("gymnasium")

from rft_mujoco.train import config as cfg  # noqa: E402
from rft_mujoco.train import zoo  # noqa: E402

ENV = "rft_mujoco/SandQuadruped-v1"
ROOT = Path(__file__).resolve().parent.parent
# the subprocesses import this tree's rft_mujoco, whatever is installed (they run in tmp_path)
SUBPROCESS_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


@pytest.mark.parametrize("algo", cfg.ALGOS)
def test_plain_yaml_reads_what_we_read(algo):
    """rl-zoo3 reads one entry with yaml.safe_load (no merging with 'default', no 1e-3 floats, policy_kwargs
    eval'd): each entry of ours gives it the values our own loader resolves."""
    path = cfg.hyperparams_path(algo)
    plain = yaml.safe_load(path.read_text())
    for env_id in plain:
        ours, _ = cfg.load_hyperparams(algo, env_id, path)
        theirs = dict(plain[env_id])
        assert isinstance(theirs["learning_rate"], float) and isinstance(theirs["n_timesteps"], int), env_id
        assert cfg.parse_policy_kwargs(theirs.pop("policy_kwargs")) == ours.pop("policy_kwargs"), env_id
        assert theirs == ours, env_id


def test_policy_kwargs_string_is_parsed_without_eval():
    assert cfg.parse_policy_kwargs("dict(log_std_init=-1.0, activation_fn=nn.ELU, net_arch=dict(pi=[8], vf=[8]))") == {
        "log_std_init": -1.0, "activation_fn": "nn.ELU", "net_arch": {"pi": [8], "vf": [8]}}
    with pytest.raises(ValueError, match="policy_kwargs"):
        cfg.parse_policy_kwargs("dict(x=__import__('os').getcwd())")
    assert cfg.parse_overrides(["n_steps:64", "gamma=0.9"]) == {"n_steps": 64, "gamma": 0.9}


def _run(*commands, cwd):
    """Each command ``[module, *args]`` run as ``python -m module args`` would run it (the module as __main__
    with its sys.argv, its SystemExit code checked), one after the other in one Python subprocess in ``cwd``:
    one start-up of torch, SB3, the zoo and rft_mujoco (about 6 s of CPU on this VM) instead of one each.
    Returns each command's stdout."""
    driver = ("import runpy, sys\n"
              f"for i, argv in enumerate({[list(c) for c in commands]!r}):\n"
              "    print(f'=== command {i}', flush=True)\n"
              "    sys.argv = list(argv)\n"
              "    try:\n"
              "        runpy.run_module(argv[0], run_name='__main__', alter_sys=True)\n"
              "    except SystemExit as exit:\n"
              "        if exit.code not in (0, None):\n"
              "            raise\n"
              "    sys.stdout.flush()\n")
    result = subprocess.run([sys.executable, "-c", driver], cwd=cwd, capture_output=True, text=True, timeout=900,
                            env=SUBPROCESS_ENV)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    outs = result.stdout.split("=== command ")[1:]
    assert [int(o.split("\n", 1)[0]) for o in outs] == list(range(len(commands))), result.stdout[-3000:]
    return [o.split("\n", 1)[1] if "\n" in o else "" for o in outs]


def test_rl_zoo3_trains_evaluates_and_enjoys_with_our_yaml(tmp_path):
    pytest.importorskip("rl_zoo3")
    common = ["--algo", "ppo", "--env", ENV, "--gym-packages", "rft_mujoco.envs", "-f", "logs",
              "--env-kwargs", "max_episode_steps:20"]
    _run(["rl_zoo3.train", *common, "-conf", str(cfg.hyperparams_path("ppo")), "-n", "128", "--seed", "0",
          "--hyperparams", "n_envs:1", "n_steps:64", "batch_size:64", "n_epochs:1",
          "--eval-freq", "64", "--eval-episodes", "1", "-tb", "tb", "--device", "cpu"],
         ["rl_zoo3.enjoy", *common, "-n", "30", "--no-render", "--exp-id", "1", "--device", "cpu"], cwd=tmp_path)
    runs = list((tmp_path / "logs" / "ppo").iterdir())
    assert len(runs) == 1
    run = runs[0]
    assert (run / "evaluations.npz").is_file() and (run / "best_model.zip").is_file()   # --eval-freq ran
    # the zoo's record of the hyperparameters it used (an OrderedDict, written by the test's own run)
    saved = dict(yaml.load(next(run.rglob("config.yml")).read_text(), Loader=yaml.UnsafeLoader))  # noqa: S506
    assert saved["n_steps"] == 64 and saved["learning_rate"] == 3.0e-4 and saved["normalize"] is True
    assert saved["callback"] == "rft_mujoco.train.callbacks.RewardTermsCallback"
    events = [p.read_bytes() for p in (tmp_path / "tb").rglob("events.out.tfevents.*")]
    assert any(b"reward_terms/tracking_lin_vel" in e for e in events), "no per-term reward scalars in TensorBoard"


@pytest.mark.parametrize("env_id", [ENV, "Pendulum-v1", "gymnasium.envs.classic_control:Pendulum-v1"])
def test_zoo_env_name_is_the_zoos(env_id):
    huggingface_sb3 = pytest.importorskip("huggingface_sb3")   # what rl-zoo3 names its folders with
    assert zoo.zoo_env_name(env_id) == str(huggingface_sb3.EnvironmentName(env_id))
    assert "/" not in zoo.zoo_env_name(env_id)


def test_zoo_config_reads_back_as_ours():
    """config.yml's policy_kwargs is the zoo's dict(...) string of our mapping, and reads back to it."""
    config = cfg.load_config(zoo.find_run("SandQuadruped-v1"))
    entry = zoo.zoo_hyperparams(config)
    assert entry["policy_kwargs"].startswith("dict(") and "activation_fn=nn.ELU" in entry["policy_kwargs"]
    parsed = cfg.parse_policy_kwargs(entry["policy_kwargs"])
    assert parsed == {**config.hyperparams["policy_kwargs"], "activation_fn": "nn.ELU"}
    assert entry["normalize"] == config.normalize and entry["n_envs"] == config.n_envs


def test_shipped_run_exported_as_copies(tmp_path):
    """A shipped run is copied, never hard-linked (the package must not change through the zoo's folder);
    the next export takes the next id, an existing one is refused."""
    run = zoo.find_run("SandQuadruped-v1")
    first = zoo.export_zoo("SandQuadruped-v1", tmp_path / "logs")
    name = zoo.zoo_env_name(ENV)
    assert first == tmp_path / "logs" / "ppo" / f"{name}_1"
    model = first / f"{name}.zip"
    assert model.read_bytes() == (run / cfg.MODEL_FILENAME).read_bytes()
    assert not model.samefile(run / cfg.MODEL_FILENAME)
    assert (first / name / "vecnormalize.pkl").is_file() and (first / name / "config.yml").is_file()
    assert sorted(p.name for p in first.glob("*.monitor.csv")) == sorted(p.name for p in (run / "monitor").iterdir())
    assert zoo.export_zoo("SandQuadruped-v1", tmp_path / "logs").name == f"{name}_2"
    assert zoo.latest_exp_id(tmp_path / "logs", "ppo", ENV) == 2
    with pytest.raises(FileExistsError, match="--overwrite"):
        zoo.export_zoo("SandQuadruped-v1", tmp_path / "logs", exp_id=1)


def test_rl_zoo3_enjoys_our_front_runs(tmp_path):
    """A run of ``python -m rft_mujoco.train train`` (tiny budget, evaluations and a checkpoint), written
    in the zoo's layout by ``python -m rft_mujoco.train zoo``, replays in ``python -m rl_zoo3.enjoy`` (final,
    best and checkpointed models). The shipped run's round trip (``zoo --run SandQuadruped-v1`` and one episode in
    ``rl_zoo3.enjoy``, with its running averages) is docs/training.md's block, run as written by
    tests/test_docs.py::test_bash_block_runs_as_written[training.md:5]: not repeated here."""
    pytest.importorskip("rl_zoo3")
    exp_name = f"{zoo.zoo_env_name(ENV)}_1"
    enjoy = ["rl_zoo3.enjoy", "--algo", "ppo", "--env", ENV, "--gym-packages", "rft_mujoco.envs", "-f", "logs",
             "--no-render", "-n", "30", "--device", "cpu", "--exp-id", "1"]
    models = {"final": [], "best": ["--load-best"], "checkpoint": ["--load-checkpoint", "64"]}
    _, out, *replays = _run(
        ["rft_mujoco.train", "train", "--algo", "ppo", "--env", ENV, "--timesteps", "128", "--n-envs", "1",
         "--hyperparams", "n_steps=64", "batch_size=64", "n_epochs=1", "--env-kwargs", "max_episode_steps=20",
         "--eval-freq", "64", "--eval-episodes", "1", "--save-freq", "64", "--runs-dir", "runs", "--run-name",
         "ours", "--no-progress-bar", "--device", "cpu"],
        ["rft_mujoco.train", "zoo", "--run", "runs/ours", "-f", "logs"],
        *([*enjoy, *extra] for extra in models.values()), cwd=tmp_path)
    assert "--exp-id 1" in out and "0 copied" in out, out    # a run of the user's: hard links
    exp = tmp_path / "logs" / "ppo" / exp_name
    assert (exp / f"{zoo.zoo_env_name(ENV)}.zip").samefile(tmp_path / "runs" / "ours" / cfg.MODEL_FILENAME)
    assert (exp / "rl_model_64_steps.zip").is_file() and (exp / "best_model.zip").is_file()
    assert len(replays) == len(models)
    for out in replays:                         # final, best and checkpointed models
        assert exp_name in out and "Loading running average" in out and "Episode Length 20" in out, out
