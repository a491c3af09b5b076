"""The sand envs' state across resets, other envs and garbage collection; their input checks
(docs/architecture.md, "State and copies")."""

import gc
import os
import warnings
import weakref

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

import rft_mujoco  # noqa: E402
import rft_mujoco.envs  # noqa: E402
from rft_mujoco.coupling.dispatch import DISPATCHER  # noqa: E402

CHEETAH = "rft_mujoco/SandHalfCheetah-v0"
QUADRUPED_V1 = "rft_mujoco/SandQuadruped-v1"


def episode(env, steps=200, seed=5):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(rng.uniform(-1.0, 1.0, size=env.action_space.shape).astype(np.float32))
        out.append(obs)
    return np.array(out)


def test_an_episode_repeats_after_check_env_and_after_other_episodes():
    env = gymnasium.make(CHEETAH)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped, skip_render_check=True)
    first = episode(env)
    again = episode(env)
    assert np.array_equal(first, again)
    env.close()


def test_creating_and_closing_another_env_leaves_a_running_episode_alone():
    def run(other):
        env = gymnasium.make(CHEETAH)
        obs, _ = env.reset(seed=1)
        rng = np.random.default_rng(1)
        out = []
        for i in range(60):
            if other and i == 20:
                second = gymnasium.make(CHEETAH)
                second.reset(seed=2)
            if other and i == 40:
                second.close()
            out.append(env.step(rng.uniform(-1, 1, size=env.action_space.shape))[0])
        env.close()
        return np.array(out)

    assert np.array_equal(run(False), run(True))


def test_an_env_dropped_without_close_detaches_its_sand():
    before = len(DISPATCHER.handles)
    env = gymnasium.make(CHEETAH)
    env.reset(seed=0)
    assert len(DISPATCHER.handles) == before + 1
    model = weakref.ref(env.unwrapped.model)
    del env
    gc.collect()
    assert len(DISPATCHER.handles) == before and model() is None     # the sand and the model are freed


@pytest.mark.parametrize("env_id", ["rft_mujoco/SandQuadruped-v0", QUADRUPED_V1])
def test_a_quadruped_action_of_the_wrong_shape_is_refused(env_id):
    env = gymnasium.make(env_id)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must have shape \(12,\)"):
        env.step(np.zeros(3))
    env.close()


@pytest.mark.parametrize("frame_skip", [0, -1, 2.5])
def test_a_frame_skip_below_one_is_refused(frame_skip):
    with pytest.raises(ValueError, match="frame_skip must be an int >= 1"):
        gymnasium.make(QUADRUPED_V1, frame_skip=frame_skip)
