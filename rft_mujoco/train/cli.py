"""Command line: ``python -m rft_mujoco.train {train,evaluate,gap,plot,zoo}`` (``--help`` on each), also installed
as ``rft-mujoco-train``.

Examples (from any directory; runs go to ./runs)::

    python -m rft_mujoco.train train --algo ppo --env rft_mujoco/SandQuadruped-v1 --seed 0
    python -m rft_mujoco.train train --algo ppo --env rft_mujoco/SandSwimmer-v0 --timesteps 200000 --n-envs 4
    python -m rft_mujoco.train train --algo sac --env Pendulum-v1 --timesteps 20000 --hyperparams learning_rate=1e-3
    python -m rft_mujoco.train train --resume runs/rft_mujoco-SandSwimmer-v0_ppo_0_20250101-120000   # after SIGTERM
    python -m rft_mujoco.train evaluate --run SandQuadruped-v1          # the shipped policy, by name
    python -m rft_mujoco.train evaluate --run runs/rft_mujoco-SandSwimmer-v0_ppo_0_20250101-120000 --episodes 10
    python -m rft_mujoco.train gap --sand runs/SAND_RUN --rigid runs/RIGID_RUN --speed 0.4
    python -m rft_mujoco.train plot runs/*SandSwimmer* --out swimmer_curves.png
    python -m rft_mujoco.train zoo --run SandQuadruped-v1 -f logs    # then: python -m rl_zoo3.enjoy ... -f logs
    tensorboard --logdir runs
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from .config import ALGOS, HYPERPARAMS_DIR, VEC_ENVS, parse_overrides

PROG = "python -m rft_mujoco.train"
"""The command's name in help and error messages and in each run's recorded command line."""

SCRIPT = "rft-mujoco-train"
"""The console script installed with the package (:func:`script_main`)."""


def _parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="{train,evaluate,gap,plot,zoo}")

    tr = sub.add_parser("train", help="train PPO or SAC; writes runs/<env>_<algo>_<seed>_<timestamp>/",
                        description=f"Train an SB3 agent. Hyperparameters come from {HYPERPARAMS_DIR.name}/<algo>.yml "
                        "(shipped with the package) "
                        "(the 'default' entry updated by the env id's entry), then --hyperparams, then the "
                        "explicit flags. The resolved configuration is saved as config.yaml in the run "
                        "directory, beside model.zip, vecnormalize.pkl, checkpoints/, monitor/ and tb/. SIGTERM "
                        "or Ctrl-C saves the run as a checkpoint and exits with 128 + the signal number (143, 130); "
                        "--resume RUN continues a run from its latest checkpoint with its config.yaml.")
    tr.add_argument("--algo", type=str.lower, choices=ALGOS, help="algorithm (required unless --resume)")
    tr.add_argument("--env", dest="env_id",
                    help="gymnasium env id, e.g. rft_mujoco/SandSwimmer-v0 or Pendulum-v1 (required unless --resume)")
    tr.add_argument("--resume", default=None, metavar="RUN",
                    help="continue the run in folder RUN (or named RUN under --runs-dir) from its latest checkpoint "
                    "(or model.zip), with its config.yaml, counting timesteps on; takes --timesteps, "
                    "--max-minutes, --eval-freq, --eval-episodes, --no-progress-bar, --verbose")
    tr.add_argument("--timesteps", type=float, default=None,
                    help="total env steps over all envs (default: n_timesteps from the YAML; with --resume: the "
                    "run's total, a larger one trains it further)")
    tr.add_argument("--max-minutes", type=float, default=None,
                    help="stop (and save) after this many minutes of wall-clock time (default: no limit)")
    tr.add_argument("--n-envs", type=int, default=None, help="parallel training envs (default: YAML n_envs, else 1)")
    tr.add_argument("--seed", type=int, default=None, help="seed of the model and of env i (seed + i) (default 0)")
    tr.add_argument("--hyperparams", nargs="+", default=[], metavar="KEY=VALUE",
                    help="override hyperparameters; values are YAML, dotted keys nest, e.g. "
                    "learning_rate=1e-3 n_steps=256 normalize=false policy_kwargs.net_arch=[64,64]")
    tr.add_argument("--env-kwargs", nargs="+", default=[], metavar="KEY=VALUE",
                    help="keyword arguments of gymnasium.make (YAML values), on top of the YAML env_kwargs")
    tr.add_argument("--hyperparams-file", default=None,
                    help=f"YAML of hyperparameters keyed by env id (default {HYPERPARAMS_DIR}/<algo>.yml)")
    tr.add_argument("--runs-dir", default="runs", help="parent folder of run directories (default runs)")
    tr.add_argument("--run-name", default=None, help="run directory name (default <env>_<algo>_<seed>_<timestamp>)")
    tr.add_argument("--save-freq", type=int, default=None,
                    help="checkpoint every this many total steps; 0 disables (default 100000)")
    tr.add_argument("--vec-env", choices=VEC_ENVS, default=None,
                    help="dummy: envs in this process (fastest on few cores); subproc: one process each")
    tr.add_argument("--device", default=None, help="torch device: auto, cpu, cuda (default auto)")
    tr.add_argument("--num-threads", type=int, default=None,
                    help="torch CPU threads; 0: torch's default (default 1, the fastest for small MLPs)")
    tr.add_argument("--eval-freq", type=int, default=0,
                    help="evaluate the policy every this many total steps on a separate env (rl-zoo3's "
                    "--eval-freq; best_model.zip and evaluations.npz in the run folder); 0: never (default)")
    tr.add_argument("--eval-episodes", type=int, default=5, help="episodes per evaluation (default 5)")
    tr.add_argument("--no-progress-bar", action="store_true", help="no tqdm/rich progress bar")
    tr.add_argument("--verbose", type=int, default=1, choices=(0, 1, 2), help="SB3 verbosity (default 1)")

    ev = sub.add_parser("evaluate", help="reload a run from its config.yaml; trained vs random vs zero action",
                        description="Rebuild env and model from RUN/config.yaml alone and report the mean and "
                        "standard deviation of the return over N episodes for the trained policy and for "
                        "random and zero-action baselines on the same seeds, plus the mean forward speed when "
                        "the env's info has 'x_velocity' or 'forward_speed'. Writes eval.json, eval.png "
                        "(bar charts and learning curve) and video.mp4 into out/eval/<run name>/ (--out).")
    ev.add_argument("--run", required=True, help="run directory (holding config.yaml and model.zip), or the name of a "
                    "shipped run (SandQuadruped-v1, SandQuadruped-v1-rigid)")
    ev.add_argument("--episodes", type=int, default=10, help="episodes per policy (default 10)")
    ev.add_argument("--seed", type=int, default=None,
                    help="episode i resets with seed + i (default: the training seed + 10000)")
    ev.add_argument("--model", default=None, help="a checkpoint to evaluate instead of RUN/model.zip")
    ev.add_argument("--out", default=None, help="output folder (default out/eval/<run name>)")
    ev.add_argument("--overwrite", action="store_true", help="replace existing eval.json, eval.png, video.mp4")
    ev.add_argument("--stochastic", action="store_true", help="sample actions instead of the deterministic policy")
    ev.add_argument("--no-video", action="store_true", help="do not render a video")
    ev.add_argument("--video-frames", type=int, default=1000, help="frame cap of the video (default 1000)")
    ev.add_argument("--window", type=int, default=10, help="moving-average window of the learning curve")
    ev.add_argument("--env-kwargs", nargs="+", default=[], metavar="KEY=VALUE",
                    help="keyword arguments of gymnasium.make (YAML values) on top of the run's env_kwargs, "
                    "e.g. solve=implicit")
    ev.add_argument("--no-commands", action="store_true",
                    help="skip the command-tracking table (envs with a velocity command, e.g. SandQuadruped-v1)")

    gp = sub.add_parser("gap", help="the sand gap: a sand-trained and a rigid-trained run, each on both grounds",
                        description="Evaluate the run trained on sand and the run trained on rigid ground "
                        "(env_kwargs ground=rigid) each on sand and on rigid ground at one forward command: "
                        "forward speed, falls, sinkage, return.")
    gp.add_argument("--sand", required=True, help="run directory (or shipped run name) of the policy trained on sand")
    gp.add_argument("--rigid", required=True,
                    help="run directory (or shipped run name) of the policy trained on rigid ground")
    gp.add_argument("--speed", type=float, default=0.4, help="commanded forward speed, m/s (default 0.4)")
    gp.add_argument("--episodes", type=int, default=3, help="episodes per cell (default 3)")
    gp.add_argument("--out", default=None, help="JSON file of the table (default: none)")
    gp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")

    pl = sub.add_parser("plot", help="learning curves (episode return vs steps) from Monitor CSVs",
                        description="Plot episode return vs environment steps from the Monitor CSVs of one "
                        "or more runs (RUN/monitor/*.monitor.csv), one curve per run.")
    pl.add_argument("runs", nargs="+", help="run directories, shipped run names, monitor folders or monitor CSV files")
    pl.add_argument("--out", default=None, help="image path (default out/plot/<run name>.png for one run, "
                    "else out/plot/learning_curves.png)")
    pl.add_argument("--overwrite", action="store_true", help="replace an existing image")
    pl.add_argument("--window", type=int, default=10, help="moving-average window (default 10)")

    zo = sub.add_parser("zoo", help="write a run in rl-zoo3's layout, for python -m rl_zoo3.enjoy",
                        description="Write RUN as the rl-zoo3 experiment FOLDER/<algo>/<env name>_<exp id>/ "
                        "(<env name>: the env id with '/' written as '-'): the model, VecNormalize statistics, "
                        "best model, checkpoints and monitor logs hard-linked (copied where the file system "
                        "refuses), config.yml and args.yml written from config.yaml. Then "
                        "`python -m rl_zoo3.enjoy --algo ALGO --env ID --gym-packages rft_mujoco.envs -f FOLDER "
                        "--exp-id N` replays it.")
    zo.add_argument("--run", required=True, help="run directory, or the name of a shipped run (SandQuadruped-v1)")
    zo.add_argument("-f", "--folder", default="logs", help="the zoo's log folder (its -f; default logs)")
    zo.add_argument("--exp-id", type=int, default=None,
                    help="experiment id N (default: the next free one, as rl-zoo3 numbers its runs)")
    zo.add_argument("--overwrite", action="store_true", help="replace an existing experiment folder")
    return parser


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); ``prog`` names it in messages."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = _parser(prog)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        if args.command == "train":
            from .experiment import Interrupted

            try:
                _train(args, argv, prog)
            except Interrupted as stopped:          # saved; the message said what and how to resume
                return stopped.exit_code
        elif args.command == "evaluate":
            from .evaluate import evaluate

            evaluate(args.run, episodes=args.episodes, seed=args.seed, model_path=args.model,
                     out_dir=args.out, deterministic=not args.stochastic, video=not args.no_video,
                     max_video_frames=args.video_frames, window=args.window, commands=not args.no_commands,
                     overwrite=args.overwrite,
                     env_kwargs=parse_overrides(args.env_kwargs, what="--env-kwargs"))
        elif args.command == "gap":
            from .commands import format_gap, gap_table

            rows = gap_table(args.sand, args.rigid, command=(args.speed, 0.0, 0.0), episodes=args.episodes,
                             out=args.out, overwrite=args.overwrite)
            print(format_gap(rows))
        elif args.command == "zoo":
            from .zoo import export_zoo

            export_zoo(args.run, args.folder, exp_id=args.exp_id, overwrite=args.overwrite)
        else:
            from pathlib import Path

            from .plot import plot
            from .runs import OUT_DIR, check_free, find_run

            runs = [r if Path(r).exists() else find_run(r) for r in args.runs]
            out = args.out or OUT_DIR / "plot" / (f"{Path(runs[0]).resolve().name}.png" if len(runs) == 1
                                                  else "learning_curves.png")
            check_free([out], overwrite=args.overwrite)
            print(f"wrote {plot(runs, out, window=args.window)}")
    except (ValueError, FileNotFoundError, FileExistsError) as err:
        parser.exit(2, f"{prog} {args.command}: error: {err}\n")
    return 0


RUN_OPTIONS = {"algo": "--algo", "env_id": "--env", "seed": "--seed", "n_envs": "--n-envs",
               "hyperparams": "--hyperparams", "env_kwargs": "--env-kwargs", "hyperparams_file": "--hyperparams-file",
               "run_name": "--run-name", "save_freq": "--save-freq", "vec_env": "--vec-env", "device": "--device",
               "num_threads": "--num-threads"}
"""``train`` options that make a run's configuration: given with ``--resume`` they are refused (the run has its own)."""
TRAIN_DEFAULTS = {"seed": 0, "save_freq": 100_000, "vec_env": "dummy", "device": "auto", "num_threads": 1}


def _train(args, argv, prog: str) -> None:
    """``train``: a new run, or ``--resume`` of one."""
    from .config import command_line, resolve_config
    from .environments import check_env_id
    from .experiment import new_run_dir, resume, train

    given = [flag for name, flag in RUN_OPTIONS.items() if getattr(args, name) not in (None, [])]
    if args.resume is not None:
        if given:
            raise ValueError(f"--resume continues a run with its own config.yaml; {', '.join(given)} cannot be "
                             "given with it (only --timesteps, --max-minutes, --eval-freq, --eval-episodes, "
                             "--runs-dir, --no-progress-bar, --verbose)")
        resume(args.resume, timesteps=args.timesteps, runs_dir=args.runs_dir, progress_bar=not args.no_progress_bar,
               verbose=args.verbose, prog=prog, max_minutes=args.max_minutes, eval_freq=args.eval_freq,
               eval_episodes=args.eval_episodes)
        return
    missing = [flag for name, flag in (("algo", "--algo"), ("env_id", "--env")) if getattr(args, name) is None]
    if missing:
        raise ValueError(f"the following arguments are required: {', '.join(missing)} (or --resume RUN)")
    for name, value in TRAIN_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    check_env_id(args.env_id)
    config = resolve_config(
        algo=args.algo, env_id=args.env_id, seed=args.seed, timesteps=args.timesteps,
        n_envs=args.n_envs, hyperparams=args.hyperparams, env_kwargs=args.env_kwargs,
        hyperparams_file=args.hyperparams_file, vec_env=args.vec_env, save_freq=args.save_freq,
        device=args.device, num_threads=args.num_threads, command=command_line(argv, prog),
    )
    train(config, new_run_dir(config, args.runs_dir, args.run_name),
          progress_bar=not args.no_progress_bar, verbose=args.verbose, prog=prog,
          max_minutes=args.max_minutes, eval_freq=args.eval_freq, eval_episodes=args.eval_episodes)


def script_main() -> int:
    """The ``rft-mujoco-train`` console script."""
    return main(prog=SCRIPT)


if __name__ == "__main__":
    sys.exit(main())
