"""SandQuadruped on MuJoCo Warp (envs/sand_quadruped_warp.py, envs/sb3_vec_env.py) on warp's CPU device."""

import os

import numpy as np
import pytest

pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (pip install 'rft_mujoco[warp]')")
wp = pytest.importorskip("warp", reason="warp-lang is not installed (pip install 'rft_mujoco[warp]')")

import gymnasium  # noqa: E402
import mujoco  # noqa: E402

import rft_mujoco  # noqa: E402
import rft_mujoco.envs  # noqa: E402
from rft_mujoco.envs import MediaRanges  # noqa: E402
from rft_mujoco.envs.sand_quadruped_warp import (BatchedSandQuadruped, QuadrupedRewardV0,  # noqa: E402
                                                 SandQuadrupedVectorEnv)

DEVICE = os.environ.get("RFT_WARP_TEST_DEVICE", "cpu")


@pytest.fixture(autouse=True)
def _quiet():
    wp.config.quiet = True
    yield
    rft_mujoco.detach_all()


def test_vector_env_api_and_same_step_autoreset():
    env = SandQuadrupedVectorEnv(3, device=DEVICE, seed=0, max_episode_steps=3, media_ranges=MediaRanges())
    try:
        assert env.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.SAME_STEP
        obs, info = env.reset(seed=0)
        assert obs.shape == (3, 49) and env.observation_space.shape == (3, 49) and env.action_space.shape == (3, 12)
        assert np.allclose(obs[:, 0], 0.30, atol=1e-6)                   # trunk height above the sand
        assert len({m.rho_c for m in env.sim.media()}) == 3               # a medium per world
        for k in range(3):
            obs, reward, terminated, truncated, info = env.step(np.zeros((3, 12)))
            assert reward.shape == (3,) and np.all(np.isfinite(reward)) and np.all(np.isfinite(obs))
        assert np.all(truncated) and not np.any(terminated)
        assert np.all(info["_final_obs"]) and info["final_obs"][0].shape == (49,)
        assert np.all(info["_final_info"]) and "reward_tracking_lin_vel" in info["final_info"]
        assert info["final_obs"][0][0] < 0.30 - 1e-3                       # the last step had sunk in
        assert np.allclose(obs[:, 0], 0.30, atol=1e-6)                     # ... the returned obs starts anew
    finally:
        env.close()


def test_commands_per_world_and_pluggable_reward():
    class Upright(QuadrupedRewardV0):
        default_weights = {"upright": 1.0, "forward": 2.0}

        def terms(self, s):
            return {"upright": s.rot[:, 2, 2], "forward": s.v_heading[:, 0]}

    sim = BatchedSandQuadruped(2, device=DEVICE, seed=1, reward=Upright())
    try:
        sim.reset(options={"command": [[0.5, 0.0, 0.0], [0.0, 0.1, -0.2]]})
        assert np.allclose(sim.command, [[0.5, 0.0, 0.0], [0.0, 0.1, -0.2]])
        sim.set_command([0.2, 0.0, 0.3], worlds=[1])
        _, reward, _, _, info = sim.step(np.zeros((2, 12)))
        assert set(k for k in info if k.startswith("reward_")) == {"reward_upright", "reward_forward"}
        assert np.allclose(reward, info["reward_upright"] + info["reward_forward"])
        assert np.allclose(info["command"][1], [0.2, 0.0, 0.3])
    finally:
        sim.close()
    with pytest.raises(ValueError, match="valid names"):
        QuadrupedRewardV0({"nope": 1.0})


def test_observation_and_reward_are_v0s_on_the_same_state():
    """A batched world's observation and reward terms equal SandQuadruped-v0's for the same state, command,
    action and previous action."""
    sim = BatchedSandQuadruped(2, device=DEVICE, seed=2)
    cpu = gymnasium.make("rft_mujoco/SandQuadruped-v0").unwrapped
    try:
        sim.reset()
        rng = np.random.default_rng(0)
        for _ in range(3):
            action = rng.uniform(-1, 1, (2, 12))
            obs, reward, _, _, info = sim.step(action)
        cpu.reset(seed=0)
        q, v = sim._qpos[0].astype(float), sim._qvel[0].astype(float)
        cpu.data.qpos[:], cpu.data.qvel[:] = q, v
        mujoco.mj_forward(cpu.model, cpu.data)
        cpu._command = sim.command[0]
        cpu._last_action = action[0]
        assert np.allclose(cpu._get_obs(), obs[0], atol=1e-9)
        v_xy, yaw_rate = cpu._heading_velocity()
        assert np.isclose(info["reward_tracking_lin_vel"][0], cpu._weights["tracking_lin_vel"] * cpu.tracking_lin_vel(v_xy))
        assert np.isclose(info["reward_tracking_ang_vel"][0], cpu._weights["tracking_ang_vel"] * cpu.tracking_ang_vel(yaw_rate))
        assert np.isclose(info["reward_upright"][0], cpu._weights["upright"] * cpu.upright())
        assert np.isclose(info["reward_lin_vel_z"][0], cpu._weights["lin_vel_z"] * cpu.lin_vel_z())
        assert np.isclose(info["reward_ang_vel_xy"][0], cpu._weights["ang_vel_xy"] * cpu.ang_vel_xy())
        assert np.isclose(info["reward_ctrl"][0], cpu._weights["ctrl"] * cpu.ctrl(action[0]))
        assert info["reward_healthy"][0] == cpu._weights["healthy"] * cpu.healthy()
        # sinkage: v0's term reads the sand's latest evaluation (inside the step's last physics step), as here
        assert np.isclose(info["reward_sinkage"][0], -cpu._weights["sinkage"] * info["sand_sinkage"][0].sum())
        assert 0.0 < info["sand_sinkage"][0].max() < 0.06
    finally:
        sim.close()
        cpu.close()


def test_sb3_vec_env_adapter():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from rft_mujoco.envs.sb3_vec_env import SB3VecEnv

    venv = VecMonitor(SB3VecEnv(BatchedSandQuadruped(2, device=DEVICE, seed=3, max_episode_steps=4)))
    try:
        obs = venv.reset()
        assert obs.shape == (2, 49)
        for k in range(4):
            obs, reward, dones, infos = venv.step(np.zeros((2, 12), dtype=np.float32))
        assert np.all(dones) and infos[0]["TimeLimit.truncated"] and infos[0]["terminal_observation"].shape == (49,)
        assert "episode" in infos[0]                                     # VecMonitor saw the episode end
        PPO("MlpPolicy", venv, n_steps=4, batch_size=8, n_epochs=1, seed=0, device="cpu").learn(8)
    finally:
        venv.close()


def test_batched_env_is_registered_where_users_find_it():
    """``rft_mujoco.envs.make_batched_sand_quadruped`` and gymnasium's vector entry point of SandQuadruped-v0
    (the default ``make_vec`` mode of the id); ``vectorization_mode="sync"`` still gives CPU envs."""
    env = rft_mujoco.envs.make_batched_sand_quadruped(2, device=DEVICE, seed=0)
    try:
        assert isinstance(env, SandQuadrupedVectorEnv) and env.num_envs == 2
    finally:
        env.close()
    for mode in ("vector_entry_point", None):
        env = gymnasium.make_vec("rft_mujoco/SandQuadruped-v0", num_envs=2, vectorization_mode=mode, device=DEVICE,
                                 seed=0, max_episode_steps=2)
        try:
            assert isinstance(env, SandQuadrupedVectorEnv) and env.sim.max_episode_steps == 2
            assert env.spec.id == "rft_mujoco/SandQuadruped-v0"
            env.reset(seed=0)
            for _ in range(2):
                _, _, _, truncated, _ = env.step(np.zeros((2, 12)))
            assert np.all(truncated)
        finally:
            env.close()
    env = gymnasium.make_vec("rft_mujoco/SandQuadruped-v0", num_envs=2, device=DEVICE)   # the registered time limit
    try:
        assert isinstance(env, SandQuadrupedVectorEnv) and env.sim.max_episode_steps == 1000
    finally:
        env.close()
    env = gymnasium.make_vec("rft_mujoco/SandQuadruped-v0", num_envs=2, vectorization_mode="sync")
    try:
        assert isinstance(env, gymnasium.vector.SyncVectorEnv)
    finally:
        env.close()


def test_the_batched_task_takes_the_implicit_solve():
    """``solve="implicit"`` reaches the batched task's sand; the robot dropped onto the sand bed (0.05 m over its
    rigid bottom) stands after 0.8 s as with the default solve: the sand carrying part of its weight, the trunk at
    the same height within 1 cm (measured 0.234-0.238 m with either solve)."""
    heights = {}
    for solve in ("explicit", "implicit"):
        sim = BatchedSandQuadruped(2, device=DEVICE, seed=0, solve=solve, use_graph=False)
        assert sim.sand.solve == solve
        sim.reset(seed=0)
        for _ in range(40):
            obs, reward, terminated, truncated, _info = sim.step(np.zeros((2, 12)))
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward)) and not np.any(terminated)
        assert np.all(sim.sand.forces(sim.data)[:, :, 2].sum(axis=1) > 5.0)       # N
        heights[solve] = obs[:, 0].copy()
    assert np.allclose(heights["explicit"], heights["implicit"], atol=0.01), heights
