"""Gymnasium sand-locomotion tasks (``import rft_mujoco.envs`` registers the ids below).

| id                                 | task                                                          |
|------------------------------------|---------------------------------------------------------------|
| ``rft_mujoco/SandSwimmer-v0``      | sandfish-like undulator swimming inside sand                  |
| ``rft_mujoco/SandQuadruped-v0``    | Go1-class quadruped tracking a planar velocity command on sand|
| ``rft_mujoco/SandQuadruped-v1``    | the same, sand on every body, rewarded for tracking the command|
| ``rft_mujoco/SandWheel-v0``        | driven wheel on a carriage pulling a drawbar load on sand     |
| ``rft_mujoco/SandAnt-v0``          | Gymnasium Ant-v5 on sand                                      |
| ``rft_mujoco/SandHalfCheetah-v0``  | Gymnasium HalfCheetah-v5 on sand                              |
| ``rft_mujoco/SandHopper-v0``       | Gymnasium Hopper-v5 on sand                                   |
| ``rft_mujoco/SandWalker2d-v0``     | Gymnasium Walker2d-v5 on sand                                 |
| ``rft_mujoco/SandHumanoid-v0``     | Gymnasium Humanoid-v5 on sand                                 |

Any other Gymnasium MuJoCo env: :func:`make_sand_env` (e.g. ``make_sand_env("Ant-v5", bed_depth_m=0.1)``).
This package needs gymnasium; the library ``rft_mujoco`` itself never imports it.
"""

from gymnasium.envs.registration import register, registry

from .sand_bed import MediaRanges

ENV_IDS = {
    "rft_mujoco/SandSwimmer-v0": ("sand_swimmer_v0:SandSwimmerEnv", 1000),
    "rft_mujoco/SandQuadruped-v0": ("sand_quadruped_v0:SandQuadrupedEnv", 1000),
    "rft_mujoco/SandQuadruped-v1": ("sand_quadruped_v1:SandQuadrupedEnv", 1000),
    "rft_mujoco/SandWheel-v0": ("sand_wheel_v0:SandWheelEnv", 500),
    "rft_mujoco/SandAnt-v0": ("sand_wrapper:SandAntEnv", 1000),
    "rft_mujoco/SandHalfCheetah-v0": ("sand_wrapper:SandHalfCheetahEnv", 1000),
    "rft_mujoco/SandHopper-v0": ("sand_wrapper:SandHopperEnv", 1000),
    "rft_mujoco/SandWalker2d-v0": ("sand_wrapper:SandWalker2dEnv", 1000),
    "rft_mujoco/SandHumanoid-v0": ("sand_wrapper:SandHumanoidEnv", 1000),
}
"""Registered ids: (entry point in this package, max_episode_steps)."""

for _id, (_entry, _steps) in ENV_IDS.items():
    if _id not in registry:
        register(id=_id, entry_point=f"{__name__}.{_entry}", max_episode_steps=_steps)


def make_sand_env(env_id: str, **kwargs):
    """Any registered Gymnasium MuJoCo env on sand (see :func:`rft_mujoco.envs.sand_wrapper.make_sand_env`)."""
    from .sand_wrapper import make_sand_env as _make

    return _make(env_id, **kwargs)


__all__ = ["ENV_IDS", "MediaRanges", "make_sand_env"]


def make_batched_sand_quadruped(num_envs: int, *, device: str | None = None, **kwargs):
    """``num_envs`` SandQuadruped-v0 tasks stepped together on MuJoCo Warp, as one ``gymnasium.vector.VectorEnv``
    (:class:`~.sand_quadruped_warp.SandQuadrupedVectorEnv`; every keyword of
    :class:`~.sand_quadruped_warp.BatchedSandQuadruped`). Needs MuJoCo Warp (``pip install 'rft_mujoco[warp]'``).
    Also the vector entry point of ``rft_mujoco/SandQuadruped-v0``: ``gymnasium.make_vec(
    "rft_mujoco/SandQuadruped-v0", num_envs=N, vectorization_mode="vector_entry_point", device="cuda:0")`` (the
    default mode of ``make_vec`` for this id; ``vectorization_mode="sync"`` or ``"async"`` gives N CPU envs)."""
    try:
        from .sand_quadruped_warp import SandQuadrupedVectorEnv
    except ImportError as exc:
        raise ImportError(f"the batched SandQuadruped needs MuJoCo Warp ({exc}): pip install 'rft_mujoco[warp]'; "
                          "or gymnasium.make_vec(..., vectorization_mode='sync') for CPU envs") from exc
    return SandQuadrupedVectorEnv(num_envs, device=device, **kwargs)


registry["rft_mujoco/SandQuadruped-v0"].vector_entry_point = f"{__name__}:make_batched_sand_quadruped"
__all__ += ["make_batched_sand_quadruped"]
