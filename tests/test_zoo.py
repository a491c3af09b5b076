"""rl-zoo3 reads our hyperparameter files and trains, evaluates (``--eval-freq``) and enjoys on our tasks;
the runs log the reward terms to TensorBoard. A tiny budget: the point is the round trip, not learning."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")
pytest.importorskip("stable_baselines3")
pytest.importorskip("gymnasium")

from rft_mujoco.train import config as cfg  # noqa: E402

ENV = "rft_mujoco/SandQuadruped-v1"


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


def _run(args, cwd):
    result = subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result.stdout


def test_rl_zoo3_trains_evaluates_and_enjoys_with_our_yaml(tmp_path):
    pytest.importorskip("rl_zoo3")
    common = ["--algo", "ppo", "--env", ENV, "--gym-packages", "rft_mujoco.envs", "-f", "logs",
              "--env-kwargs", "max_episode_steps:20"]
    _run(["rl_zoo3.train", *common, "-conf", str(cfg.hyperparams_path("ppo")), "-n", "128", "--seed", "0",
          "--hyperparams", "n_envs:1", "n_steps:64", "batch_size:64", "n_epochs:1",
          "--eval-freq", "64", "--eval-episodes", "1", "-tb", "tb", "--device", "cpu"], tmp_path)
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
    _run(["rl_zoo3.enjoy", *common, "-n", "30", "--no-render", "--exp-id", "1", "--device", "cpu"], tmp_path)
