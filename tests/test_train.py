"""Tests of ``python -m rft_mujoco.train`` (``rft_mujoco/train/``; the same from the repository root): CLI
help from any directory, config resolution and round trip, and smoke runs that train, save, reload from
``config.yaml`` alone and evaluate.

The main smoke run uses ``rft_mujoco/SandSwimmer-v0`` when it is registered (100-step episodes through the
``max_episode_steps`` env kwarg of ``gymnasium.make``), else ``Pendulum-v1`` with a warning; a second one
runs ``rft_mujoco/SandQuadruped-v1`` with its own hyperparameter entry.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

pytest.importorskip("stable_baselines3")
gym = pytest.importorskip("gymnasium")

from rft_mujoco.train import config as cfg  # noqa: E402
from rft_mujoco.train.cli import main  # noqa: E402
from rft_mujoco.train.environments import check_env_id, sand_env_ids  # noqa: E402

SAND_ID = "rft_mujoco/SandSwimmer-v0"
QUADRUPED_V1 = "rft_mujoco/SandQuadruped-v1"
SAND_IDS = ("rft_mujoco/SandSwimmer-v0", "rft_mujoco/SandAnt-v0", "rft_mujoco/SandHalfCheetah-v0",
            "rft_mujoco/SandQuadruped-v0", QUADRUPED_V1)
PROG = "python -m rft_mujoco.train"


def _smoke_env_id() -> str:
    sand_env_ids()  # registers the sand tasks if the package provides them
    if SAND_ID in gym.registry:
        return SAND_ID
    warnings.warn(f"{SAND_ID} is not registered: the training smoke test falls back to Pendulum-v1",
                  stacklevel=2)
    return "Pendulum-v1"


# --- command line -------------------------------------------------------------------------------

@pytest.mark.parametrize("command", [[], ["train"], ["evaluate"], ["plot"]])
def test_help_from_any_directory(command, tmp_path):
    """The installed package runs outside the repository (cwd: an empty temporary folder)."""
    result = subprocess.run([sys.executable, "-m", "rft_mujoco.train", *command, "--help"], cwd=tmp_path,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"usage: {PROG}")
    expected = {(): "evaluate", ("train",): "--hyperparams", ("evaluate",): "--episodes",
                ("plot",): "--window"}[tuple(command)]
    assert expected in result.stdout
    assert not list(tmp_path.iterdir())


def test_console_script_and_repository_root(tmp_path):
    script = shutil.which("rft-mujoco-train", path=str(Path(sys.executable).parent))
    if script is None:
        pytest.skip("the rft-mujoco-train console script is not installed beside this Python")
    result = subprocess.run([script, "train", "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: rft-mujoco-train train")
    at_root = subprocess.run([sys.executable, "-m", "rft_mujoco.train", "--help"], cwd=ROOT, capture_output=True,
                             text=True, timeout=60)
    assert at_root.returncode == 0, at_root.stderr
    assert at_root.stdout.startswith(f"usage: {PROG}")


def test_hyperparameters_are_package_data():
    import importlib.resources

    shipped = importlib.resources.files("rft_mujoco.train") / "hyperparams"
    assert {p.name for p in shipped.iterdir()} >= {"ppo.yml", "sac.yml"}
    assert cfg.hyperparams_path("ppo") == cfg.HYPERPARAMS_DIR / "ppo.yml"
    assert Path(str(shipped / "ppo.yml")).resolve() == cfg.hyperparams_path("ppo").resolve()


def test_unknown_algo_is_a_clear_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--algo", "dqn", "--env", "Pendulum-v1"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'dqn'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="algo must be one of ppo, sac, got 'dqn'"):
        cfg.check_algo("dqn")


def test_unknown_env_id_lists_sand_ids(capsys):
    with pytest.raises(ValueError, match="unknown env id 'NoSuchEnv-v0'") as err:
        check_env_id("NoSuchEnv-v0")
    sand = sand_env_ids()
    assert all(env_id in str(err.value) for env_id in sand)
    if not sand:
        assert "none" in str(err.value)
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--algo", "ppo", "--env", "NoSuchEnv-v0"])
    assert exit_info.value.code == 2
    assert "unknown env id 'NoSuchEnv-v0'" in capsys.readouterr().err


def test_env_id_without_namespace_suggests_the_sand_id():
    sand_env_ids()
    if SAND_ID not in gym.registry:
        pytest.skip(f"{SAND_ID} is not registered")
    with pytest.raises(ValueError, match=f"close matches: {SAND_ID}"):
        check_env_id("SandSwimmer-v0")


# --- configuration ------------------------------------------------------------------------------

def test_overrides_parse_as_yaml_with_dotted_keys():
    assert cfg.parse_overrides(["learning_rate=1e-3", "n_steps=64", "policy_kwargs.net_arch=[32, 32]",
                                "normalize=false", "ent_coef=auto"]) == {
        "learning_rate": 1e-3, "n_steps": 64, "policy_kwargs": {"net_arch": [32, 32]},
        "normalize": False, "ent_coef": "auto"}
    with pytest.raises(ValueError, match="key=value, got 'learning_rate'"):
        cfg.parse_overrides(["learning_rate"])


def test_resolution_order():
    config = cfg.resolve_config(algo="PPO", env_id=SAND_ID, seed=3, n_envs=2,
                                hyperparams=["learning_rate=1e-3", "policy_kwargs.net_arch.pi=[32]",
                                             "n_timesteps=5000"],
                                env_kwargs=["max_episode_steps=100"])
    assert config.algo == "ppo"
    assert config.hyperparams_entries == ["default", SAND_ID]
    assert config.hyperparams["gamma"] == 0.9999  # the env entry over the default
    assert config.hyperparams["learning_rate"] == 1e-3  # --hyperparams over the YAML
    assert config.hyperparams["policy_kwargs"]["net_arch"] == {"pi": [32], "vf": [64, 64]}
    assert config.n_envs == 2 and config.n_timesteps == 5000 and isinstance(config.n_timesteps, int)
    assert config.env_kwargs == {"max_episode_steps": 100}
    assert config.normalize["gamma"] == 0.9999  # VecNormalize discounts with the algorithm's gamma
    assert "n_timesteps" not in config.hyperparams and "normalize" not in config.hyperparams
    explicit = cfg.resolve_config(algo="ppo", env_id=SAND_ID, timesteps=1e4,
                                  hyperparams=["n_timesteps=5000"])
    assert explicit.n_timesteps == 10_000  # --timesteps over everything
    unlisted = cfg.resolve_config(algo="sac", env_id="Pendulum-v1")
    assert unlisted.hyperparams_entries == ["default"] and unlisted.normalize is None


def test_config_round_trip(tmp_path):
    config = cfg.resolve_config(algo="sac", env_id=SAND_ID, seed=7, timesteps=1234,
                                hyperparams=["learning_rate=lin_1e-3", "normalize=true",
                                             "policy_kwargs.activation_fn=relu"],
                                env_kwargs=["max_episode_steps=50", "label=1e-3"],
                                command=f"{PROG} train --algo sac")
    path = cfg.save_config(config, tmp_path / "run")
    assert path == tmp_path / "run" / "config.yaml"
    loaded = cfg.load_config(tmp_path / "run")
    assert loaded == config
    assert cfg.load_config(path) == config
    assert loaded.versions["stable_baselines3"] == cfg.package_versions()["stable_baselines3"]
    kwargs = cfg.algo_kwargs(loaded)
    assert kwargs["learning_rate"](1.0) == pytest.approx(1e-3) and kwargs["learning_rate"](0.0) == 0.0
    import torch

    assert kwargs["policy_kwargs"]["activation_fn"] is torch.nn.ReLU
    assert loaded.hyperparams["policy_kwargs"]["activation_fn"] == "relu"  # the saved config stays plain


def test_load_config_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no config.yaml"):
        cfg.load_config(tmp_path)
    (tmp_path / "config.yaml").write_text("algo: ppo\nsurprise: 1\n")
    with pytest.raises(ValueError, match=r"unknown keys \['surprise'\]"):
        cfg.load_config(tmp_path)


@pytest.mark.parametrize("algo", cfg.ALGOS)
def test_hyperparams_files_cover_the_sand_tasks(algo):
    table = cfg.load_yaml(cfg.hyperparams_path(algo))
    assert {"default", *SAND_IDS} <= set(table)
    import inspect

    accepted = set(inspect.signature(cfg.algo_class(algo).__init__).parameters)
    for env_id in table:
        config = cfg.resolve_config(algo=algo, env_id=env_id)
        assert set(cfg.algo_kwargs(config)) <= accepted, (env_id, set(config.hyperparams) - accepted)


def test_unknown_hyperparameter_is_a_clear_error(tmp_path):
    from rft_mujoco.train.experiment import train

    config = cfg.resolve_config(algo="ppo", env_id="Pendulum-v1", timesteps=64,
                                hyperparams=["learnin_rate=1e-3"])
    with pytest.raises(ValueError, match=r"PPO does not accept \['learnin_rate'\]"):
        train(config, tmp_path / "run", progress_bar=False, verbose=0)


# --- learning curves ----------------------------------------------------------------------------

def test_monitor_files_merge_by_end_time(tmp_path):
    from rft_mujoco.train.plot import load_monitor, moving_average, plot

    (tmp_path / "monitor").mkdir()
    (tmp_path / "monitor" / "0.monitor.csv").write_text(
        '#{"t_start": 100.0, "env_id": "x"}\nr,l,t\n1.0,10,1.0\n3.0,10,3.0\n')
    (tmp_path / "monitor" / "1.monitor.csv").write_text(
        '#{"t_start": 101.0, "env_id": "x"}\nr,l,t\n2.0,5,1.0\n')
    data = load_monitor(tmp_path)
    assert data["returns"].tolist() == [1.0, 2.0, 3.0]
    assert data["timesteps"].tolist() == [10, 15, 25]
    assert data["time_s"].tolist() == [1.0, 2.0, 3.0]
    assert moving_average(data["returns"], 2).tolist() == [1.0, 1.5, 2.5]
    assert plot([tmp_path], tmp_path / "curve.png").is_file()
    with pytest.raises(ValueError, match="no finished episodes"):
        plot([tmp_path / "empty"], tmp_path / "none.png")


# --- smoke runs ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    """2048 PPO steps (2 envs x n_steps 256) with VecNormalize and checkpoints, through the CLI."""
    env_id = _smoke_env_id()
    runs = tmp_path_factory.mktemp("runs")
    start = time.perf_counter()
    code = main(["train", "--algo", "ppo", "--env", env_id, "--timesteps", "2048", "--n-envs", "2",
                 "--seed", "1", "--hyperparams", "n_steps=256", "batch_size=128", "n_epochs=2",
                 "--env-kwargs", "max_episode_steps=100", "--save-freq", "1024", "--runs-dir", str(runs),
                 "--no-progress-bar", "--verbose", "0"])
    assert code == 0
    (run,) = runs.iterdir()
    return env_id, run, time.perf_counter() - start


@pytest.mark.slow
def test_ppo_smoke_run_writes_the_run_directory(ppo_run):
    env_id, run, seconds = ppo_run
    assert run.name.startswith(f"{env_id.replace('/', '-')}_ppo_1_")
    for name in ("config.yaml", "model.zip", "vecnormalize.pkl", "checkpoints/model_1024_steps.zip",
                 "checkpoints/model_vecnormalize_2048_steps.pkl", "monitor/0.monitor.csv",
                 "monitor/1.monitor.csv"):
        assert (run / name).is_file(), name
    assert list((run / "tb").glob("PPO_1/events.out.tfevents.*"))
    config = cfg.load_config(run)
    assert (config.algo, config.env_id, config.seed, config.n_envs, config.n_timesteps) == (
        "ppo", env_id, 1, 2, 2048)
    assert config.hyperparams["n_steps"] == 256 and config.env_kwargs == {"max_episode_steps": 100}
    assert config.command.startswith(f"{PROG} train --algo ppo")
    assert f"{PROG} evaluate --run" in (run / "config.yaml").read_text()
    print(f"PPO smoke training on {env_id}: {seconds:.1f} s")


@pytest.mark.slow
def test_ppo_smoke_run_evaluates_from_config_alone(ppo_run, tmp_path):
    from rft_mujoco.train.evaluate import evaluate

    env_id, run, _ = ppo_run
    start = time.perf_counter()
    results = evaluate(run, episodes=2, out_dir=tmp_path, max_video_frames=20)
    seconds = time.perf_counter() - start
    assert set(results["policies"]) == {"trained", "random", "zero"}
    assert results["seeds"] == [10_001, 10_002]  # training seed + 10000 + i
    for summary in results["policies"].values():
        assert len(summary["returns"]) == 2 and summary["lengths"] == [100, 100]
    if env_id == SAND_ID:
        assert results["speed_key"] == "x_velocity"
        assert all(s["speed_mean"] is not None for s in results["policies"].values())
    assert results["video"] is not None or results["video_message"].startswith("video skipped")
    assert json.loads((tmp_path / "eval.json").read_text())["policies"].keys() == results["policies"].keys()
    assert (tmp_path / "eval.png").is_file()
    # same seeds, same numbers: the evaluation is reproducible
    again = evaluate(run, episodes=1, out_dir=tmp_path / "again", video=False)
    for name in ("trained", "random", "zero"):
        assert again["policies"][name]["returns"][0] == pytest.approx(results["policies"][name]["returns"][0])
    checkpoint = evaluate(run, episodes=1, out_dir=tmp_path / "checkpoint", video=False,
                          model_path=run / "checkpoints" / "model_1024_steps.zip")
    assert checkpoint["model"].endswith("model_1024_steps.zip")
    print(f"evaluation on {env_id}: {seconds:.1f} s")


def test_sac_smoke_run_on_pendulum(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(["train", "--algo", "sac", "--env", "Pendulum-v1", "--timesteps", "300",
                 "--hyperparams", "learning_starts=100", "batch_size=32", "policy_kwargs.net_arch=[32,32]",
                 "--save-freq", "0", "--runs-dir", str(tmp_path), "--run-name", "sac", "--no-progress-bar",
                 "--verbose", "0"])
    assert code == 0
    run = tmp_path / "sac"
    assert (run / "model.zip").is_file() and not (run / "vecnormalize.pkl").exists()
    assert not (run / "checkpoints").exists()
    assert main(["evaluate", "--run", str(run), "--episodes", "1", "--no-video"]) == 0
    out = capsys.readouterr().out
    assert "trained" in out and "zero" in out and "no forward speed" in out
    assert json.loads((tmp_path / "out" / "eval" / "sac" / "eval.json").read_text())["speed_key"] is None
    assert not (run / "eval").exists()                       # outputs never go into the run folder
    with pytest.raises(SystemExit) as exit_info:             # and are not overwritten without --overwrite
        main(["evaluate", "--run", str(run), "--episodes", "1", "--no-video"])
    assert exit_info.value.code == 2 and "pass --overwrite" in capsys.readouterr().err


@pytest.mark.slow
def test_quadruped_v1_smoke_train_save_load_evaluate(tmp_path):
    """SandQuadruped-v1 with its YAML entry (2 x 128 PPO steps instead of 4 x 1024), then evaluation
    (trained, random, zero) and a few video frames, rebuilt from config.yaml."""
    from rft_mujoco.train import commands
    from rft_mujoco.train.evaluate import evaluate

    start = time.perf_counter()
    code = main(["train", "--algo", "ppo", "--env", QUADRUPED_V1, "--timesteps", "256", "--n-envs", "2",
                 "--seed", "2", "--hyperparams", "n_steps=128", "batch_size=128", "n_epochs=1",
                 "--env-kwargs", "max_episode_steps=40", "--save-freq", "0", "--runs-dir", str(tmp_path),
                 "--run-name", "v1", "--no-progress-bar", "--verbose", "0"])
    trained_s = time.perf_counter() - start
    assert code == 0
    run = tmp_path / "v1"
    assert (run / "model.zip").is_file() and (run / "vecnormalize.pkl").is_file()
    config = cfg.load_config(run)
    assert config.hyperparams_entries == ["default", QUADRUPED_V1]
    assert config.hyperparams["policy_kwargs"]["net_arch"] == {"pi": [256, 256], "vf": [256, 256]}
    assert config.normalize is not None and config.hyperparams["gamma"] == 0.99
    start = time.perf_counter()
    results = evaluate(run, episodes=1, out_dir=tmp_path / "eval", max_video_frames=5)
    assert set(results["policies"]) == {"trained", "random", "zero"}
    assert results["speed_key"] == "x_velocity"
    assert results["policies"]["zero"]["lengths"] == [40]
    assert results["video"] is not None or results["video_message"].startswith("video skipped")
    rows = results["commands"]                      # the command-tracking table of the README
    assert [(r["policy"], tuple(r["command"])) for r in rows] == [
        (p, c) for p in ("trained", "zero", "random") for c in commands.COMMANDS]
    assert all(np.isfinite(r["vx"]) and r["sinkage_m"] > 0.0 and 0 <= r["falls"] <= 1 for r in rows)
    gap = commands.gap_table(run, run, episodes=1, out=tmp_path / "gap.json")
    assert [(r["trained_on"], r["ground"]) for r in gap] == [("sand", "sand"), ("sand", "rigid"),
                                                             ("rigid", "sand"), ("rigid", "rigid")]
    assert gap[0]["sinkage_m"] > 0.0 and gap[1]["sinkage_m"] == 0.0     # no sand on the rigid floor
    assert "trained on" in commands.format_gap(gap) and (tmp_path / "gap.json").is_file()
    # the same policy under the implicit sand solve: --env-kwargs on top of the run's own, recorded
    assert main(["evaluate", "--run", str(run), "--episodes", "1", "--no-video", "--no-commands",
                 "--out", str(tmp_path / "implicit"), "--env-kwargs", "solve=implicit"]) == 0
    implicit = json.loads((tmp_path / "implicit" / "eval.json").read_text())
    assert implicit["env_kwargs"] == {**config.env_kwargs, "solve": "implicit"}
    assert implicit["policies"]["trained"]["returns"] != results["policies"]["trained"]["returns"]
    (row,) = commands.command_table(run, commands=[(0.4, 0.0, 0.0)], episodes=1, baselines=False,
                                    env_kwargs={"solve": "implicit"})
    assert np.isfinite(row["vx"]) and row["sinkage_m"] > 0.0
    print(f"SandQuadruped-v1 smoke: training {trained_s:.1f} s, evaluation {time.perf_counter() - start:.1f} s")


PRETRAINED = Path(__file__).resolve().parent.parent / "rft_mujoco" / "train" / "pretrained" / "SandQuadruped-v1"


def test_the_shipped_policy_loads_by_name_and_walks_forward_on_sand(tmp_path, monkeypatch):
    """rft_mujoco/train/pretrained/SandQuadruped-v1 (the README's policy), found by its name from any
    directory and rebuilt from its config.yaml, moves the robot forward at a 0.4 m/s command (a short
    rollout; no speed asserted beyond "forward")."""
    import rft_mujoco.train

    for name in ("model.zip", "vecnormalize.pkl", "config.yaml"):
        assert (PRETRAINED / name).stat().st_size < 5_000_000, name          # small files
    monkeypatch.chdir(tmp_path)
    assert rft_mujoco.train.find_run("SandQuadruped-v1").resolve() == PRETRAINED.resolve()
    act, env, config = rft_mujoco.train.load_run("SandQuadruped-v1")
    assert config.env_id == QUADRUPED_V1
    try:
        obs, _ = env.reset(seed=123, options={"command": (0.4, 0.0, 0.0)})
        x0 = env.unwrapped.data.qpos[0]
        for _ in range(150):                                                  # 3 s
            obs, _, terminated, truncated, _ = env.step(act(obs))
            assert not terminated
        assert env.unwrapped.data.qpos[0] - x0 > 0.1
    finally:
        env.close()


# --- interrupted and resumed runs ------------------------------------------------------------------

def _train_process(args, cwd):
    """``python -m rft_mujoco.train train ARGS`` of this checkout in a subprocess (stdout and stderr together)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen([sys.executable, "-m", "rft_mujoco.train", "train", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _interrupt_when_stepping(process, run, signum, timeout=240.0):
    """Send ``signum`` once the run's first env finished an episode (training is stepping); its output."""
    monitor = run / "monitor" / "0.monitor.csv"
    deadline = time.monotonic() + timeout
    while not (monitor.is_file() and len(monitor.read_text().splitlines()) >= 3):
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"training never stepped (exit {process.poll()}):\n{process.communicate()[0]}")
        time.sleep(0.2)
    process.send_signal(signum)
    return process.communicate(timeout=timeout)[0]


def _interrupted_steps(output, signame):
    match = re.search(rf"interrupted by {signame} at (\d+) of \d+ steps", output)
    assert match, output
    return int(match.group(1))


def _resume_in_process(args, cwd, capsys, monkeypatch):
    """``train --resume ...`` through the CLI in this process (the interrupted run is the subprocess; the resume
    needs no signal, and this saves a start-up of torch and SB3, about 6 s of CPU): (exit code, stdout + stderr)."""
    monkeypatch.chdir(cwd)
    capsys.readouterr()
    code = main(["train", *args])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def test_sigterm_saves_the_run_and_resume_continues_it(tmp_path, capsys, monkeypatch):
    """PPO with VecNormalize and no periodic checkpoints (--save-freq 0): SIGTERM saves a checkpoint and exits
    with 143 without a traceback; --resume (by name) trains on from it, counting the steps on."""
    from rft_mujoco.train.runs import latest_checkpoint, model_steps

    runs, run = tmp_path / "runs", tmp_path / "runs" / "ppo"
    process = _train_process(["--algo", "ppo", "--env", "Pendulum-v1", "--timesteps", "1000000", "--n-envs", "1",
                              "--hyperparams", "n_steps=64", "batch_size=64", "n_epochs=1", "normalize=true",
                              "--env-kwargs", "max_episode_steps=20", "--save-freq", "0", "--runs-dir", str(runs),
                              "--run-name", "ppo", "--no-progress-bar", "--verbose", "0"], tmp_path)
    output = _interrupt_when_stepping(process, run, signal.SIGTERM)
    assert process.returncode == 143, output
    assert "Traceback" not in output and f"resume with: {PROG} train --resume {run}\n" in output
    steps = _interrupted_steps(output, "SIGTERM")
    for name in (f"checkpoints/model_{steps}_steps.zip", f"checkpoints/model_vecnormalize_{steps}_steps.pkl",
                 "model.zip", "vecnormalize.pkl"):
        assert (run / name).is_file(), name
    assert latest_checkpoint(run).model == run / "checkpoints" / f"model_{steps}_steps.zip"
    assert model_steps(run / f"checkpoints/model_{steps}_steps.zip") == steps

    code, output = _resume_in_process(["--resume", "ppo", "--runs-dir", str(runs), "--timesteps", str(steps + 128),
                                       "--no-progress-bar", "--verbose", "0"], tmp_path, capsys, monkeypatch)
    assert code == 0, output
    assert f"resuming from checkpoints/model_{steps}_steps.zip at {steps} steps" in output
    assert model_steps(run / "model.zip") >= steps + 128                  # the total grew
    assert cfg.load_config(run).n_timesteps == steps + 128
    assert (run / "monitor" / f"resumed_{steps}" / "0.monitor.csv").is_file()
    assert len(list((run / "tb").glob("PPO_1/events.out.tfevents.*"))) == 2     # the same TensorBoard run
    assert latest_checkpoint(run).model == run / "model.zip"


def test_sigint_saves_an_off_policy_run_with_its_replay_buffer(tmp_path, capsys, monkeypatch):
    from rft_mujoco.train.runs import model_steps

    run = tmp_path / "sac"
    process = _train_process(["--algo", "sac", "--env", "Pendulum-v1", "--timesteps", "1000000", "--hyperparams",
                              "learning_starts=40", "batch_size=32", "buffer_size=2000",
                              "policy_kwargs.net_arch=[32,32]",
                              "--env-kwargs", "max_episode_steps=20", "--save-freq", "0", "--runs-dir", str(tmp_path),
                              "--run-name", "sac", "--no-progress-bar", "--verbose", "0"], tmp_path)
    output = _interrupt_when_stepping(process, run, signal.SIGINT)
    assert process.returncode == 130 and "Traceback" not in output, output
    steps = _interrupted_steps(output, "SIGINT")
    assert (run / "checkpoints" / f"model_replay_buffer_{steps}_steps.pkl").is_file()
    code, output = _resume_in_process(["--resume", str(run), "--timesteps", str(steps + 30), "--no-progress-bar",
                                       "--verbose", "0"], tmp_path, capsys, monkeypatch)
    assert code == 0, output
    loaded = re.search(r"replay buffer of (\d+) transitions loaded", output)
    assert loaded and 0 < int(loaded.group(1)) <= steps, output          # (the interrupted step is not in it)
    assert model_steps(run / "model.zip") >= steps + 30


def test_resume_refuses_what_it_cannot_do(tmp_path, capsys):
    config = cfg.resolve_config(algo="ppo", env_id="Pendulum-v1", timesteps=100)
    cfg.save_config(config, tmp_path / "empty")
    cases = [(["--resume", str(tmp_path / "empty")], "nothing to resume in .*no model_<steps>_steps.zip"),
             (["--resume", "nope", "--runs-dir", str(tmp_path)], "no run 'nope' to resume"),
             (["--resume", str(tmp_path / "empty"), "--algo", "sac", "--seed", "3"],
              "--algo, --seed cannot be given with it"),
             (["--algo", "ppo"], "required: --env \\(or --resume RUN\\)")]
    for args, message in cases:
        with pytest.raises(SystemExit) as exit_info:
            main(["train", *args])
        assert exit_info.value.code == 2 and re.search(message, capsys.readouterr().err), args
