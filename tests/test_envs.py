"""The Gymnasium sand tasks (envs/, installed as rft_mujoco.envs): API, determinism, physics sanity."""

import copy
import gc
import os
import warnings

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

import rft_mujoco  # noqa: E402
import rft_mujoco.envs  # noqa: E402
from rft_mujoco.envs import ENV_IDS, MediaRanges, make_sand_env  # noqa: E402
from rft_mujoco.envs.camera import track_body  # noqa: E402
from rft_mujoco.envs.sand_quadruped_v1 import DEFAULT_REWARD_WEIGHTS, scripted_trot  # noqa: E402
from rft_mujoco.envs.sand_swimmer_v0 import serpenoid_action  # noqa: E402

QUADRUPED_V1 = "rft_mujoco/SandQuadruped-v1"
NATIVE_IDS = ["rft_mujoco/SandSwimmer-v0", "rft_mujoco/SandQuadruped-v0", QUADRUPED_V1, "rft_mujoco/SandWheel-v0"]
WRAPPED_IDS = ["rft_mujoco/SandAnt-v0", "rft_mujoco/SandHalfCheetah-v0", "rft_mujoco/SandHopper-v0",
               "rft_mujoco/SandWalker2d-v0", "rft_mujoco/SandHumanoid-v0"]

RANDOM_STEPS = {env_id: 1000 for env_id in ENV_IDS}
RANDOM_STEPS.update({"rft_mujoco/SandWalker2d-v0": 300, "rft_mujoco/SandHumanoid-v0": 300})
"""Random steps per id in the NaN test: 1000, except 300 for Walker2d and Humanoid (slowest per step,
and their wrapper path is the same code as Ant/HalfCheetah/Hopper, which run the full 1000)."""

SWIMMER_MIN_SPEED_M_S = 0.01
"""The serpenoid gait must move the swimmer's centre of mass forward at least this fast (m/s)."""

ALLOWED_CHECK_ENV_WARNINGS = ("is probably too low", "is probably too high")
"""check_env warnings every unbounded-observation MuJoCo env gets (Gymnasium's own Ant included)."""



def rollout(env, seed, steps):
    """Observations (steps + 1, n) and rewards (steps,) under seeded random actions (no resets)."""
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    observations, rewards = [obs], []
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            break
    return np.array(observations), np.array(rewards)


# --- API -------------------------------------------------------------------------------------------
def test_all_ids_registered():
    assert set(NATIVE_IDS + WRAPPED_IDS) == set(ENV_IDS)
    for env_id in ENV_IDS:
        assert env_id in gymnasium.registry


def test_library_does_not_import_gymnasium():
    import subprocess
    import sys

    code = "import sys, rft_mujoco, rft_mujoco.coupling.handle; sys.exit('gymnasium' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_check_env(env_id):
    env = gymnasium.make(env_id)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)  # "human" needs a display
    env.close()
    other = [str(w.message) for w in caught if not any(a in str(w.message) for a in ALLOWED_CHECK_ENV_WARNINGS)
             and "settotalmass" not in str(w.message)]
    assert not other, other


@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_random_steps_finite(env_id):
    env = gymnasium.make(env_id)
    obs, _ = env.reset(seed=1)
    env.action_space.seed(1)
    assert env.observation_space.contains(obs)
    for _ in range(RANDOM_STEPS[env_id]):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        assert np.all(np.isfinite(info["sand_force"])) and np.all(info["sand_sinkage"] >= 0)
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()


@pytest.mark.parametrize("env_id", NATIVE_IDS + ["rft_mujoco/SandAnt-v0"])
def test_same_seed_same_rollout(env_id):
    kwargs = {"media_ranges": MediaRanges()}
    a, b = gymnasium.make(env_id, **kwargs), gymnasium.make(env_id, **kwargs)   # two envs, one process
    obs_a, rew_a = rollout(a, 7, 60)
    obs_b, rew_b = rollout(b, 7, 60)
    media_a, media_b = a.unwrapped.sand.media, b.unwrapped.sand.media
    obs_c, _ = rollout(a, 8, 60)
    a.close()
    b.close()
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    assert media_a == media_b
    assert obs_c.shape != obs_a.shape or not np.array_equal(obs_c, obs_a)


def test_render_rgb_array():
    env = gymnasium.make("rft_mujoco/SandSwimmer-v0", render_mode="rgb_array", width=96, height=64)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    try:
        frame = env.render()
    except Exception as exc:  # no GL on this machine
        env.close()
        pytest.skip(f"offscreen rendering unavailable: {exc}")
    env.close()
    assert frame.shape == (64, 96, 3) and frame.dtype == np.uint8 and frame.std() > 0


@pytest.mark.parametrize("env_id, n_bodies", [("rft_mujoco/SandSwimmer-v0", 7), ("rft_mujoco/SandQuadruped-v0", 4),
                                              ("rft_mujoco/SandWheel-v0", 1), ("rft_mujoco/SandHopper-v0", 1)])
def test_sand_observation_option(env_id, n_bodies):
    plain = gymnasium.make(env_id)
    env = gymnasium.make(env_id, include_sand_in_observation=True)
    assert env.observation_space.shape[0] == plain.observation_space.shape[0] + 4 * n_bodies
    plain.close()
    obs, _ = env.reset(seed=0)
    for _ in range(20):
        obs, *_, info = env.step(env.action_space.sample())
    sand = obs[-4 * n_bodies:].reshape(n_bodies, 4)
    np.testing.assert_allclose(sand[:, :3], info["sand_force"])
    np.testing.assert_allclose(sand[:, 3], info["sand_sinkage"])
    env.close()


def test_media_randomization_in_ranges():
    ranges = MediaRanges(rho_c=(1200.0, 1300.0), mu_int=(0.3, 0.35), mu_surf=(0.1, 0.5))
    env = gymnasium.make("rft_mujoco/SandWheel-v0", media_ranges=ranges)
    seen = set()
    for seed in range(4):
        env.reset(seed=seed)
        media = env.unwrapped.sand.media
        assert env.unwrapped.sand.handle.media is media
        assert 1200 <= media.rho_c <= 1300 and 0.3 <= media.mu_int <= 0.35
        assert 0.1 <= media.mu_surf <= media.mu_int
        seen.add(media.rho_c)
    env.close()
    assert len(seen) == 4
    with pytest.raises(ValueError, match="rho_c"):
        MediaRanges(rho_c=(10.0, 20.0))


@pytest.mark.parametrize("env_id", ["rft_mujoco/SandQuadruped-v1", "rft_mujoco/SandAnt-v0"])
def test_solve_option_reaches_the_sand(env_id):
    """``solve="implicit"`` runs the implicit sand solve (native task and wrapped env); it repeats from a seed,
    and it changes the simulation (the two solves are different physics, not a label)."""
    a, b = gymnasium.make(env_id, solve="implicit"), gymnasium.make(env_id, solve="implicit")
    default = gymnasium.make(env_id)
    assert a.unwrapped.sand.handle.solve == "implicit"
    assert default.unwrapped.sand.handle.solve == "explicit"
    obs_a, rew_a = rollout(a, 3, 40)
    obs_b, rew_b = rollout(b, 3, 40)
    obs_d, _ = rollout(default, 3, 40)
    for env in (a, b, default):
        env.close()
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    assert not np.array_equal(obs_a, obs_d)
    with pytest.raises(ValueError, match="solve must be one of"):
        gymnasium.make(env_id, solve="semi-implicit")


@pytest.mark.parametrize("stages, per_step", [(None, 2), ("midpoint", 2), ("all", 4), ("first", 1)])
def test_the_wrapped_envs_evaluate_the_rk4_stages_asked_for(stages, per_step):
    """The Gymnasium sand envs (RK4) evaluate the sand at a step's first two stages by default
    (``rk4_stages="midpoint"``), at every stage or at the first when asked; an env step is 5 MuJoCo steps."""
    env = gymnasium.make("rft_mujoco/SandAnt-v0", **({} if stages is None else {"rk4_stages": stages}))
    u = env.unwrapped
    assert u.model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 and u.frame_skip == 5
    assert u.sand.handle.rk4_stages == (stages or "midpoint")
    env.reset(seed=0)
    before = u.sand.handle.evaluations
    env.step(np.zeros(env.action_space.shape))
    assert u.sand.handle.evaluations - before == 5 * per_step
    env.close()


def test_bad_arguments_say_what_is_wrong():
    with pytest.raises(ValueError, match="drive"):
        gymnasium.make("rft_mujoco/SandWheel-v0", drive="speed")
    with pytest.raises(ValueError, match="reward_weights"):
        gymnasium.make("rft_mujoco/SandQuadruped-v0", reward_weights={"speed": 1.0})
    with pytest.raises(ValueError, match="bed_depth_m"):
        gymnasium.make("rft_mujoco/SandAnt-v0", bed_depth_m=-0.1)
    with pytest.raises(ValueError, match="rk4_stages must be one of"):
        gymnasium.make("rft_mujoco/SandAnt-v0", rk4_stages="odd")
    with pytest.raises(ValueError, match="not a MuJoCo env"):
        make_sand_env("CartPole-v1")


# --- the wrapper -----------------------------------------------------------------------------------
@pytest.mark.parametrize("base_id, feet", [("Ant-v5", None), ("HalfCheetah-v5", ["bshin", "bfoot", "fshin", "ffoot"]),
                                           ("Hopper-v5", ["foot"])])
def test_wrapper_puts_env_on_sand(base_id, feet):
    base = gymnasium.make(base_id)
    env = make_sand_env(base_id)
    u = env.unwrapped
    assert env.observation_space == base.observation_space and env.action_space == base.action_space
    assert env.spec.max_episode_steps == base.spec.max_episode_steps
    base.close()
    if feet is not None:
        assert u.sand.body_names == feet
    else:   # Ant: the four unnamed lower legs, the leaves of the tree
        assert len(u.sand.body_ids) == 4 and all(u.model.body_parentid[b] not in (0, 1) for b in u.sand.body_ids)
    floor = u.model.geom("floor").id
    assert u.model.geom_contype[floor] == 0 and u.model.geom_conaffinity[floor] == 0
    env.reset(seed=0)
    env.action_space.seed(0)
    loaded = False
    for _ in range(60):
        _, _, terminated, _, info = env.step(env.action_space.sample())
        loaded |= bool(np.any(info["sand_sinkage"] > 0) and np.any(info["sand_force"][:, 2] > 0))
        if terminated:
            break
    assert loaded, "the feet never sank into the sand"
    assert floor not in u.data.contact.geom[:u.data.ncon].ravel()
    env.close()


def test_wrapper_rigid_bottom():
    env = make_sand_env("Hopper-v5", bed_depth_m=0.05)
    u = env.unwrapped
    bottom = u.model.geom("sand_bottom0").id
    assert u.model.geom_pos[bottom][2] == pytest.approx(-0.05) and u.model.geom_rgba[bottom][3] == 0
    assert u.model.geom_contype[bottom] == 1
    env.close()


def cfrc_ext_without_sand(model, data):
    """Reference: cfrc_ext recomputed on a copy of the data with no applied body wrench at all."""
    ref = copy.copy(data)
    ref.xfrc_applied[:] = 0.0
    mujoco.mj_rnePostConstraint(model, ref)
    return ref.cfrc_ext.copy()


def test_sand_does_not_leak_into_cfrc_ext():
    """Ant-v5 observes cfrc_ext and charges a contact cost on it: with the default
    ``sand_in_contact_forces=False`` both must see rigid contacts only, and the dynamics must not change."""
    kwargs = dict(bed_depth_m=0.03, contact_cost_weight=5e-4, contact_force_range=(-1e3, 1e3))
    clean = gymnasium.make("rft_mujoco/SandAnt-v0", **kwargs)
    leaky = gymnasium.make("rft_mujoco/SandAnt-v0", sand_in_contact_forces=True, **kwargs)
    uc, ul = clean.unwrapped, leaky.unwrapped
    clean.reset(seed=3)
    leaky.reset(seed=3)
    clean.action_space.seed(3)
    n_cfrc = uc.data.cfrc_ext[1:].size
    sand_seen = contacts_seen = False
    for _ in range(80):
        action = clean.action_space.sample()
        obs_c, rew_c, term_c, _, info_c = clean.step(action)
        obs_l, rew_l, term_l, _, info_l = leaky.step(action)
        np.testing.assert_array_equal(uc.data.qpos, ul.data.qpos)   # same dynamics
        expected = cfrc_ext_without_sand(uc.model, uc.data)
        np.testing.assert_allclose(uc.data.cfrc_ext, expected, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(obs_c[-n_cfrc:], expected[1:].ravel(), rtol=1e-9, atol=1e-9)
        cost = 5e-4 * np.sum(np.square(np.clip(expected, -1e3, 1e3)))
        assert info_c["reward_contact"] == pytest.approx(-cost, rel=1e-9, abs=1e-12)
        # The sand wrench is still applied (and the coupling still recognises its rows).
        sand = np.abs(info_c["sand_force"]).sum() > 0
        if sand:
            sand_seen = True
            rows = uc.sand.body_ids
            assert np.abs(uc.data.xfrc_applied[rows]).sum() > 0
            assert not np.allclose(ul.data.cfrc_ext[rows], uc.data.cfrc_ext[rows])
        contacts_seen |= uc.data.ncon > 0 and np.abs(expected).sum() > 0
        if term_c or term_l:
            break
    clean.close()
    leaky.close()
    assert sand_seen and contacts_seen


# --- the native tasks --------------------------------------------------------------------------------
def swim(wave_direction, seconds=2.0, **kwargs):
    env = gymnasium.make("rft_mujoco/SandSwimmer-v0", reset_noise_scale=0.0, **kwargs)
    _, info = env.reset(seed=0)
    x0 = info["x_position"]
    dt = env.unwrapped.dt
    steps = int(round(seconds / dt))
    for i in range(steps):
        _, _, _, _, info = env.step(serpenoid_action(i * dt, waves_per_body=wave_direction).astype(np.float32))
    env.close()
    return (info["x_position"] - x0) / (steps * dt)


def test_swimmer_serpenoid_swims_forward():
    """A head-to-tail travelling wave swims forward (+x); the tail-to-head wave swims backward."""
    forward = swim(+1.0)
    backward = swim(-1.0)
    assert forward > SWIMMER_MIN_SPEED_M_S
    assert backward < -SWIMMER_MIN_SPEED_M_S


def test_the_swimmer_env_scales_the_animal_for_the_explicit_solve_and_the_animal_swims_implicitly():
    """The bundled model is the animal (22 g); SandSwimmer-v0 scales it 100x by default (the explicit solve's mass
    scaling); with density_scale=1 and the implicit solve the animal itself swims forward with the serpenoid. Not
    at the scaled body's speed: at the serpenoid's 2 Hz the scaled body's joint inertia takes much of its servos'
    0.3 N m (tracking 0.47 rad RMS against the animal's 0.17, measured 2026-12-04), so the two bodies make
    different waves."""
    env = gymnasium.make("rft_mujoco/SandSwimmer-v0")
    assert env.unwrapped.model.body_mass.sum() == pytest.approx(100 * 0.0219, rel=0.01)
    env.close()
    animal = gymnasium.make("rft_mujoco/SandSwimmer-v0", density_scale=1.0, solve="implicit")
    assert animal.unwrapped.model.body_mass.sum() == pytest.approx(0.0219, rel=0.01)
    animal.close()
    with pytest.raises(ValueError, match="density_scale must be > 0"):
        gymnasium.make("rft_mujoco/SandSwimmer-v0", density_scale=0.0)
    with pytest.warns(rft_mujoco.SandSetupWarning, match="pass solve='implicit'"):
        gymnasium.make("rft_mujoco/SandSwimmer-v0", density_scale=1.0).close()
    assert swim(+1.0, 1.0, density_scale=1.0, solve="implicit") > SWIMMER_MIN_SPEED_M_S


def mean_speed(policy, timestep_s, steps=150, start=50):
    env = gymnasium.make("rft_mujoco/SandSwimmer-v0", timestep_s=timestep_s,
                         frame_skip=int(round(0.02 / timestep_s)), reset_noise_scale=0.0)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    speeds = []
    for i in range(steps):
        action = serpenoid_action(i * 0.02) if policy == "serpenoid" else rng.uniform(-0.9, 0.9, 6)
        _, _, _, _, info = env.step(action.astype(np.float32))
        if i >= start:
            speeds.append(info["x_velocity"])
    env.close()
    return float(np.mean(speeds))


def test_swimmer_speed_is_step_converged():
    """The default 5 ms step agrees with a 1 ms step within 15%, and random flailing does not swim
    (the unscaled 17 g model gave +0.1 m/s for random actions at 5 ms: a numerical ratchet)."""
    coarse, fine = mean_speed("serpenoid", 0.005), mean_speed("serpenoid", 0.001)
    assert fine > SWIMMER_MIN_SPEED_M_S
    assert abs(coarse - fine) < 0.15 * fine
    assert abs(mean_speed("random", 0.005)) < 0.1 * fine


def test_quadruped_command_and_termination():
    env = gymnasium.make("rft_mujoco/SandQuadruped-v0")
    obs, info = env.reset(seed=0, options={"command": (0.4, 0.0, 0.1)})
    np.testing.assert_array_equal(obs[46:49], [0.4, 0.0, 0.1])
    np.testing.assert_array_equal(info["command"], [0.4, 0.0, 0.1])
    _, _, _, _, info = env.step(np.zeros(12, np.float32))
    names = {"tracking_lin_vel", "tracking_ang_vel", "upright", "healthy", "lin_vel_z", "ang_vel_xy", "ctrl",
             "action_rate", "sinkage"}
    assert {f"reward_{n}" for n in names} <= set(info)
    u = env.unwrapped
    qpos = u.data.qpos.copy()
    qpos[3:7] = [0.0, 1.0, 0.0, 0.0]           # upside down
    u.set_state(qpos, u.data.qvel.copy())
    *_, terminated, _, _ = env.step(np.zeros(12, np.float32))
    env.close()
    assert terminated
    with pytest.raises(ValueError, match="command"):
        gymnasium.make("rft_mujoco/SandQuadruped-v0").reset(options={"command": (1.0, 2.0)})


def test_wheel_slip_drive_holds_slip_and_reports_pull():
    env = gymnasium.make("rft_mujoco/SandWheel-v0", drive="slip", resolution="coarse")
    env.reset(seed=0)
    for _ in range(100):
        _, _, _, _, info = env.step(np.array([0.3], np.float32))
    env.close()
    assert info["slip"] == pytest.approx(0.3, abs=0.03)
    assert info["sinkage_m"] > 0 and info["wheel_torque_nm"] > 0
    assert np.isfinite(info["drawbar_pull_n"])
    # In steady state the carriage holds what the sand pushes: pull ~ sand force along x.
    assert info["drawbar_pull_n"] == pytest.approx(info["sand_force"][0, 0], abs=0.5)


def test_wheel_torque_drive_carries_the_load():
    env = gymnasium.make("rft_mujoco/SandWheel-v0", drawbar_load_n=4.0, resolution="coarse")
    env.reset(seed=0)
    for _ in range(50):
        _, _, _, _, info = env.step(np.zeros(1, np.float32))   # no torque: the load drags the wheel back
    env.close()
    assert info["drawbar_load_n"] == 4.0 and info["x_position"] <= 1e-3


def test_compiling_and_two_env_kinds_in_one_process():
    """mujoco 4 refuses to compile while a Python callback is installed; the library works around it."""
    ant = gymnasium.make("rft_mujoco/SandAnt-v0")
    swimmer = gymnasium.make("rft_mujoco/SandSwimmer-v0")   # compiled while Ant's sand is attached
    mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody>"
                                   "</mujoco>")
    ant.reset(seed=0)
    swimmer.reset(seed=0)
    for _ in range(5):
        ant.step(ant.action_space.sample())
        swimmer.step(swimmer.action_space.sample())
    ant.close()
    swimmer.step(swimmer.action_space.sample())
    swimmer.close()
    assert not rft_mujoco.coupling.dispatch.DISPATCHER.handles


# --- SandQuadruped-v1 ------------------------------------------------------------------------------
V1_SHORT_EPISODE_STEPS = 150
"""One short v1 episode: 3 s (the trot ramps up over its first 0.5 s)."""

V1_COMMAND = (0.4, 0.0, 0.0)
"""The command of the scripted-trot comparison: 0.4 m/s forward (the trot's nominal speed)."""


def episode_return(env, policy, seed, steps, command=V1_COMMAND):
    obs, _ = env.reset(seed=seed, options={"command": command})
    total = 0.0
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
        total += reward
        if terminated or truncated:
            break
    return total


def test_quadruped_v1_scores_walking_above_standing():
    """The reward pays for tracking the command: under 0.4 m/s forward the scripted trot scores well above
    the zero action (standing in the home pose), which scores above random actions (which fall)."""
    env = gymnasium.make(QUADRUPED_V1)
    zero = episode_return(env, lambda obs: np.zeros(12, np.float32), 0, V1_SHORT_EPISODE_STEPS)
    trot = episode_return(env, scripted_trot(env, speed_mps=0.4), 0, V1_SHORT_EPISODE_STEPS)
    env.action_space.seed(0)
    rand = episode_return(env, lambda obs: env.action_space.sample(), 0, V1_SHORT_EPISODE_STEPS)
    env.close()
    assert trot > 1.5 * zero > 0
    assert rand < zero


def test_quadruped_v1_reward_terms_and_info():
    env = gymnasium.make(QUADRUPED_V1)
    obs, info = env.reset(seed=0, options={"command": (0.4, 0.0, 0.1)})
    np.testing.assert_array_equal(obs[46:49], [0.4, 0.0, 0.1])
    np.testing.assert_array_equal(info["command"], [0.4, 0.0, 0.1])
    env.action_space.seed(0)
    u = env.unwrapped
    for _ in range(30):
        _, reward, terminated, _, info = env.step(env.action_space.sample() * 0.3)
        terms = {k[len("reward_"):]: v for k, v in info.items() if k.startswith("reward_")}
        assert set(terms) == set(DEFAULT_REWARD_WEIGHTS)
        assert reward == pytest.approx(max(sum(terms.values()), 0.0), abs=1e-12)   # only_positive_rewards
        assert info["sand_force"].shape == (17, 3) and info["sand_sinkage"].shape == (17,)
        assert not terminated
    # the weighted terms are the methods times the weights
    assert terms["torques"] == pytest.approx(-2e-5 * np.sum(np.square(u.data.actuator_force)))
    assert terms["healthy"] == DEFAULT_REWARD_WEIGHTS["healthy"]
    env.close()
    raw = gymnasium.make(QUADRUPED_V1, only_positive_rewards=False, reward_weights={"healthy": 0.0})
    raw.reset(seed=0)
    _, reward, *_, info = raw.step(np.ones(12, np.float32))
    assert info["reward_healthy"] == 0.0
    assert reward == pytest.approx(sum(v for k, v in info.items() if k.startswith("reward_")), abs=1e-12)
    raw.close()


def test_quadruped_v1_sand_on_every_body():
    """Every body of the robot feels the sand; standing, the feet and the lower calves are in it."""
    env = gymnasium.make(QUADRUPED_V1)
    u = env.unwrapped
    assert len(u.sand.body_names) == u.model.nbody - 1 == 17
    env.reset(seed=0)
    for _ in range(25):
        *_, info = env.step(np.zeros(12, np.float32))
    env.close()
    rows = {n: i for i, n in enumerate(u.sand.body_names)}
    for leg in ("FL", "FR", "RL", "RR"):
        assert info["sand_force"][rows[f"{leg}_foot"], 2] > 0
        assert info["sand_sinkage"][rows[f"{leg}_calf"]] > 0
    assert info["sand_sinkage"][rows["trunk"]] == 0


def test_quadruped_v1_commands_resets_and_termination():
    env = gymnasium.make(QUADRUPED_V1)
    commands = np.array([env.reset(seed=s)[1]["command"] for s in range(20)])
    assert np.all((commands[:, 0] >= 0.0) & (commands[:, 0] <= 0.6)) and np.ptp(commands[:, 0]) > 0.3
    assert np.all(commands[:, 1] == 0.0)
    assert np.all(np.abs(commands[:, 2]) <= 0.5) and np.ptp(commands[:, 2]) > 0.3
    u = env.unwrapped
    home = u.model.key("home").qpos
    obs, _ = env.reset(seed=3)
    assert np.abs(u.data.qpos[7:] - home[7:]).max() <= 0.05          # home with small noise
    np.testing.assert_array_equal(u.data.qpos[:7], home[:7])
    qpos = u.data.qpos.copy()
    qpos[3:7] = [0.0, 1.0, 0.0, 0.0]                                  # upside down
    u.set_state(qpos, u.data.qvel.copy())
    *_, terminated, _, _ = env.step(np.zeros(12, np.float32))
    assert terminated
    env.reset(seed=0)
    qpos = u.data.qpos.copy()
    qpos[2] = 0.08                                                    # trunk down on the sand
    u.set_state(qpos, np.zeros(u.model.nv))
    *_, terminated, _, _ = env.step(np.zeros(12, np.float32))
    assert terminated
    with pytest.raises(ValueError, match="command"):
        env.reset(options={"command": (1.0, 2.0)})
    env.close()
    with pytest.raises(ValueError, match="reward_weights"):
        gymnasium.make(QUADRUPED_V1, reward_weights={"upright": 1.0})
    with pytest.raises(ValueError, match="command_ranges"):
        gymnasium.make(QUADRUPED_V1, command_ranges=((0.6, 0.0), (0, 0), (0, 0)))


def test_quadruped_v1_sand_observation_per_leg():
    env = gymnasium.make(QUADRUPED_V1, include_sand_in_observation=True)
    assert env.observation_space.shape == (49 + 16,)
    env.reset(seed=0)
    for _ in range(20):
        obs, *_, info = env.step(np.zeros(12, np.float32))
    names = env.unwrapped.sand.body_names
    env.close()
    sand = obs[49:].reshape(4, 4)
    for i, leg in enumerate(("FL", "FR", "RL", "RR")):
        rows = [k for k, n in enumerate(names) if n.startswith(f"{leg}_")]
        np.testing.assert_allclose(sand[i, :3], info["sand_force"][rows].sum(axis=0))
        assert sand[i, 3] == info["sand_sinkage"][rows].max() > 0


# --- cameras that follow the robot -----------------------------------------------------------------
def robot_pixels(frame, kind):
    """Boolean mask of the robot in an RGB frame: the quadruped's greys (not the yellow sand, its shadow or
    the blue sky), the Ant's tan."""
    rgb = frame.astype(float)
    if kind == "grey":
        return (np.abs(rgb[..., 0] - rgb[..., 2]) < 12) & (rgb.mean(axis=-1) < 200)
    return (rgb[..., 0] - rgb[..., 2] > 60) & (rgb[..., 0] > 120)


def frames_before_and_after_a_move(env, dx_m=3.0):
    env.reset(seed=0)
    before = env.render()
    u = env.unwrapped
    qpos = u.data.qpos.copy()
    qpos[0] += dx_m
    u.set_state(qpos, u.data.qvel.copy())
    return before, env.render()


@pytest.mark.parametrize("env_id, kind", [(QUADRUPED_V1, "grey"), ("rft_mujoco/SandAnt-v0", "tan")])
def test_render_camera_follows_the_robot(env_id, kind):
    """Moved 3 m, the robot is still where it was in the frame; with the free camera it has left it."""
    masks = {}
    for camera in ("default", "free"):
        # Gymnasium's OffScreenViewer.__del__ releases whatever GL context is current, even after close():
        # collect the closed envs of earlier tests now, not in the middle of this one (black frames).
        gc.collect()
        extra = {} if camera == "default" else {"camera_id": -1}
        env = gymnasium.make(env_id, render_mode="rgb_array", width=160, height=120, **extra)
        try:
            before, after = frames_before_and_after_a_move(env)
        except Exception as exc:  # no GL on this machine
            env.close()
            pytest.skip(f"offscreen rendering unavailable: {exc}")
        env.close()
        masks[camera] = robot_pixels(before, kind), robot_pixels(after, kind)
    seen, moved = masks["default"]
    assert seen.sum() > 200
    assert (seen & moved).sum() > 0.6 * seen.sum()          # the same pixels: the camera followed
    seen_free, moved_free = masks["free"]
    assert (seen_free & moved_free).sum() < 0.3 * seen_free.sum()


def test_track_body_switches_a_free_camera_only():
    free = gymnasium.make("rft_mujoco/SandQuadruped-v0", render_mode="rgb_array")   # Gymnasium's free camera
    assert track_body(free)
    config = free.unwrapped.mujoco_renderer.default_cam_config
    assert config["type"] == mujoco.mjtCamera.mjCAMERA_TRACKING and config["trackbodyid"] == 1
    free.close()
    fixed = gymnasium.make(QUADRUPED_V1, render_mode="rgb_array")                   # the model's track camera
    assert not track_body(fixed)
    assert fixed.unwrapped.mujoco_renderer.camera_id == fixed.unwrapped.model.camera("track").id
    fixed.close()
