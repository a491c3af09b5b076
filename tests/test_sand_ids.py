"""``make_sand_env`` returns exactly the env that its ``spec.id`` names (results logged under one id compare)."""

from __future__ import annotations

import pytest

gymnasium = pytest.importorskip("gymnasium")

from rft_mujoco.envs import make_sand_env  # noqa: E402


@pytest.mark.parametrize("base_id, sand_id", [("Ant-v5", "rft_mujoco/SandAnt-v0"),
                                              ("Hopper-v5", "rft_mujoco/SandHopper-v0"),
                                              ("Ant-v4", "rft_mujoco/SandAnt_v4-v0")])
def test_make_sand_env_is_its_registered_id(base_id, sand_id):
    env = make_sand_env(base_id)
    again = gymnasium.make(env.spec.id)
    try:
        assert env.spec.id == sand_id and sand_id in gymnasium.registry
        assert repr(env.unwrapped.sand.handle) == repr(again.unwrapped.sand.handle)       # bodies, elements, medium
        assert env.spec.max_episode_steps == again.spec.max_episode_steps == gymnasium.spec(base_id).max_episode_steps
    finally:
        env.close()
        again.close()


def test_make_sand_env_records_its_arguments():
    env = make_sand_env("Hopper-v5", bed_depth_m=0.05)
    try:
        assert env.spec.id == "rft_mujoco/SandHopper-v0" and env.spec.kwargs["bed_depth_m"] == 0.05
        again = gymnasium.make(env.spec)
        assert repr(again.unwrapped.sand.handle) == repr(env.unwrapped.sand.handle)
        again.close()
    finally:
        env.close()
