"""Command line: ``python -m rft_mujoco <command>`` (``--help`` on each): demo, view, validate, bench, stability,
swim, quasistatic, anymass, glide, footprint, ruts, prints, compile."""

from __future__ import annotations

import argparse
import importlib
import sys

COMMANDS = {
    "demo": ("rft_mujoco.studies.demo", "quadruped trotting on sand, headless: summary table, plot and video"),
    "view": ("rft_mujoco.studies.demo", "the demo scene in the interactive mujoco.viewer with sand force arrows"),
    "validate": ("rft_mujoco.studies.validation", "the paper's validation intrusions: force tables and plots"),
    "bench": ("rft_mujoco.studies.bench", "speed and speed-accuracy benchmarks: tables and plots"),
    "stability": ("rft_mujoco.studies.stability", "drop / drag / rotate stability study: table and stability map"),
    "swim": ("rft_mujoco.studies.swim", "sand-swimming: wave efficiency against A/lambda, against experiments"),
    "quasistatic": ("rft_mujoco.studies.quasistatic", "quasi-static references: the swimmer's inertia-free limit, "
                    "rest depths of the load-path scenes"),
    "anymass": ("rft_mujoco.studies.anymass", "the swimmer at the animal's density and at 100x: each sand solve "
                "against the quasi-static limit"),
    "compile": ("rft_mujoco.compiled.warmup", "compile the numba kernels now (into the user's cache; --ship: into "
                "the package, for a wheel)"),
    "glide": ("rft_mujoco.studies.glide", "a quadruped on slanted mesh lower legs set down on sand: does it "
              "stand still?"),
    "footprint": ("rft_mujoco.studies.footprint", "a box's footprint in a deformable surface, set back into it and "
                  "loaded twice as much"),
    "ruts": ("rft_mujoco.studies.ruts", "the sand wheel rig driven over its own rut on a deformable surface"),
    "prints": ("rft_mujoco.studies.prints", "the demo quadruped trotting on a deformable surface: footprints, a "
               "frame, the cost"),
}


STUDY_DEPENDENCIES = ("matplotlib", "imageio", "imageio_ffmpeg", "gymnasium")
"""Packages of the ``studies`` (and ``envs``) extras: a missing one gives an install hint, not a traceback."""


def version_line() -> str:
    """``rft_mujoco <version> (mujoco <version>, numba <version>, python <version>)``."""
    import platform

    import mujoco

    import rft_mujoco
    from rft_mujoco.compiled import jit

    numba = getattr(jit.numba, "__version__", "not available")
    return (f"rft_mujoco {rft_mujoco.__version__} (mujoco {mujoco.__version__}, numba {numba}, "
            f"python {platform.python_version()})")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="python -m rft_mujoco", description=__doc__)
    parser.add_argument("command", choices=sorted(COMMANDS), help="; ".join(
        f"{k}: {v[1]}" for k, v in COMMANDS.items()))
    parser.add_argument("--version", action="version", version=version_line())
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return 0 if argv else 2
    if argv[0] == "--version":
        print(version_line())
        return 0
    args, rest = parser.parse_known_args(argv[:1])
    try:
        module = importlib.import_module(COMMANDS[args.command][0])
        return int(module.main(argv[1:], command=args.command) or 0)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] in STUDY_DEPENDENCIES:
            print(f"python -m rft_mujoco {args.command}: needs {exc.name}, which is not installed; install the "
                  f"studies' dependencies: pip install 'rft_mujoco[studies]' (and [envs] for the env "
                  "benchmarks)", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
