"""Compile (or load from the cache) the coupling's kernels: the native route's two phases, which contain the
evaluation of every terrain and setting (a route over no handle on a tiny model), and the native callbacks.

On a first use with two or more cores, the rest treatment (:func:`rft_mujoco.compiled.route.rest_phase`,
half of the compile) compiles in a second Python process (``python -m rft_mujoco.compiled.warmup --part
rest``) into the same cache while this one compiles phase 2 (first: the element pass both need), phase 1
and the native callbacks; this process then loads it from the cache (and compiles it itself if the second process failed). Set
``RFT_MUJOCO_COMPILE_PROCESSES=1`` to compile in this process only.

Compiled at their first use instead: the Python path's phases (:func:`rft_mujoco.compiled.evaluate.broadphase`,
:func:`~rft_mujoco.compiled.evaluate.evaluate`; the dispatcher runs the native route from a model's first
evaluation on, and the Python path only with observers, after an error or where the route cannot be
built) and :func:`rft_mujoco.compiled.law.element_forces`. The progress line reports those compiles too.

The implicit solve's native evaluation (:mod:`rft_mujoco.compiled.implicit_route`) compiles at the first route with
a ``solve="implicit"`` handle (``compile --implicit`` ahead of time).

``python -m rft_mujoco compile`` runs this ahead of time: into the user's cache, or with ``--ship`` into
the package's :data:`~rft_mujoco.compiled.jit.SHIPPED_ROOT` so that a wheel built afterwards carries the
machine code (:func:`rft_mujoco.compiled.jit.seed_from_shipped`).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import mujoco

from rft_mujoco.compiled import evaluate as ev
from rft_mujoco.compiled import jit, locks, route, table
from rft_mujoco.compiled.jit import types

_MODEL = """<mujoco><worldbody>
  <body name="a" pos="0 0 0.01"><freejoint/><geom type="sphere" size="0.03" mass="1"/>
    <body name="b" pos="0.04 0 0"><joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.1"/></body></body>
  <geom type="box" pos="0.3 0 0" size="0.02 0.02 0.02"/>
</worldbody></mujoco>"""

PROCESSES_ENV = "RFT_MUJOCO_COMPILE_PROCESSES"
"""Environment variable: "1" compiles in the calling process only (default: a second process when cold)."""


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def rest_cached() -> bool:
    """Whether the cache holds an index for ``rest_phase`` (for some CPU: numba still compiles on another one)."""
    import glob

    return bool(glob.glob(os.path.join(jit.cache_dir(), "compiled", "route.rest_phase-*.nbi")))


_LOCKED_REST_ARGS = (("free", "mob", "rft_g", "u", "total"), "dt", "ng", "settings", ("w", "rest"),
                     ("a", "v", "cap", "flow", "idx", "block", "rhs", "size", "weight", "lin", "perm", "x"),
                     ("keep_rest", "state"), ("twist", "chain", "zt"), locks.LOCK)
"""The arguments of ``locks.locked_rest`` as ``evaluate._rest`` passes them (after ``nl``, before ``check``): the
``ws`` / ``hc`` field passed, or ``dt`` / ``ng`` (float64 / int64 scalars); a tuple of names: a bundle of those
fields (``rest.REST_GROUPS``, ``REST_OUT``, ``REST_WORK``, ``REST_KEPT``, ``locks.MOTION``, ``locks.LOCK``)."""


def locked_rest_signature() -> tuple:
    """The numba argument types of ``locks.locked_rest`` as the rest phase calls it (arrays as the route's table
    gives them: C layout, the schema's dtype and rank; bundles as tuples of them)."""
    kinds = dict(ev.WORK_FIELDS + ev.HANDLE_FIELDS)

    def typed(name):
        if isinstance(name, tuple):
            return types.Tuple([typed(n) for n in name])
        return types.float64 if name == "dt" else types.int64 if name == "ng" else table.array_type(kinds[name])
    return (types.int64, *(typed(name) for name in _LOCKED_REST_ARGS), types.boolean)


def compile_rest_part() -> None:
    """The second process's part: ``locks.locked_rest``, then ``route.rest_phase``. The rest phase's typing meets
    the element pass (``element_pass.wrenches``) before ``locked_rest``; compiled in this order, this process
    reaches it after the first process, which compiles it first (for phase 2), has cached it, and loads it
    instead of compiling it a second time (measured: 16 CPU s of both processes' 55 s each, before)."""
    locks.locked_rest.compile(locked_rest_signature())
    route.cfunc_of("rest_phase")


def start_rest_process():
    """A second process compiling ``rest_phase`` into the cache (None: one core, warm cache, or switched off)."""
    if (not jit.PER_USER_CACHE or _cores() < 2 or os.environ.get(PROCESSES_ENV, "") == "1"
            or rest_cached()):
        return None
    package_parent = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [package_parent, os.environ.get("PYTHONPATH")])),
               **{jit.CACHE_ENV: jit.cache_root(), PROCESSES_ENV: "1"})
    try:
        return subprocess.Popen([sys.executable, "-m", "rft_mujoco.compiled.warmup", "--part", "rest"], env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    except OSError:
        return None


def run(progress=None) -> None:
    """Compile or load phase 2, phase 1, the native callbacks and the rest treatment (this order), the rest
    treatment in a second process when cold (:func:`start_rest_process`); then run both phases once on a tiny
    model. ``progress``: the package's progress reporter (told what compiles where)."""
    worker = start_rest_process()
    if progress is not None:
        progress.plan(parallel=worker is not None)

    def now(what):
        if progress is not None:
            progress.now(what)

    try:
        now("route.phase2")
        route.cfunc_of("phase2")     # first: its element pass (``wrenches``) is cached before the rest needs it
        now("route.phase1")
        route.cfunc_of("phase1")
        now("the native callbacks")
        from rft_mujoco.compiled import native  # noqa: F401  (compiles the native callbacks)
        if worker is not None:
            now("route.rest_phase in the second process")
            _, err = worker.communicate()
            if worker.returncode != 0 and progress is not None:
                last = (err.decode(errors="replace").strip().splitlines() or [""])[-1]
                progress.say(f"rft_mujoco: the second compile process failed (exit {worker.returncode}: {last}); "
                             "compiling here")
            worker = None
        now("route.rest_phase")
        route.cfunc_of("rest_phase")
        model = mujoco.MjModel.from_xml_string(_MODEL)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        try:
            route.warm_up(model, data)
        except RuntimeError:                         # no route here (route.efc_layout): the Python path runs
            pass
    finally:
        if worker is not None and worker.poll() is None:    # interrupted: no compile left running behind
            worker.kill()
            worker.wait()


def main(argv: list[str] | None = None, command: str = "compile") -> int:
    """``python -m rft_mujoco compile``: compile the kernels now (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog=f"python -m rft_mujoco {command}",
        description="Compile the numba kernels now, into the user's cache (what a first use would do), or with "
                    "--ship into the package (rft_mujoco/compiled/machine_code/<key>) for a wheel built afterwards; "
                    "a first use then copies them into the user's cache where the sources, the versions and the "
                    "CPU match, and compiles otherwise.")
    parser.add_argument("--ship", action="store_true", help="compile into a new empty cache and copy it into "
                        "the package (replacing machine code shipped for other sources or versions)")
    parser.add_argument("--implicit", action="store_true", help="also the implicit solve's native evaluation "
                        "(attach(..., solve='implicit'); otherwise compiled at its first use; always with --ship)")
    parser.add_argument("--part", choices=("rest",), help=argparse.SUPPRESS)   # the second process
    args = parser.parse_args(argv)
    if args.part == "rest":
        compile_rest_part()
        return 0
    if not jit.AVAILABLE:
        print(f"numba is not available ({jit.IMPORT_ERROR}): nothing to compile", file=sys.stderr)
        return 2
    if args.ship:
        return _ship()
    from rft_mujoco import compiled

    start = time.perf_counter()
    compiled.ensure_compiled()
    if args.implicit:
        from rft_mujoco.compiled import implicit_route
        implicit_route.cfunc_address()
    print(f"rft_mujoco: kernels ready in {jit.cache_dir()} ({time.perf_counter() - start:.0f} s)")
    return 0


def _ship() -> int:
    import shutil
    import tempfile

    key = os.path.basename(jit.cache_dir())
    with tempfile.TemporaryDirectory(prefix="rft_mujoco_ship_") as tmp:
        env = dict(os.environ, **{jit.CACHE_ENV: tmp, jit.NO_SHIPPED_ENV: "1"})
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "rft_mujoco.compiled.warmup", "--implicit"], env=env, check=True)
        built = os.path.join(tmp, key)
        if not jit.has_index(built):
            print(f"no machine code was written into {built}", file=sys.stderr)
            return 1
        if os.path.isdir(jit.SHIPPED_ROOT):
            shutil.rmtree(jit.SHIPPED_ROOT)
        shutil.copytree(built, os.path.join(jit.SHIPPED_ROOT, key))
    files = [os.path.join(d, f) for d, _, fs in os.walk(jit.SHIPPED_ROOT) for f in fs]
    size = sum(os.path.getsize(f) for f in files)
    print(f"rft_mujoco: {len(files)} files ({size / 1e6:.1f} MB) of machine code for "
          f"{jit.numba.config.CPU_NAME or jit.numba.core.codegen.ll.get_host_cpu_name()} in "
          f"{os.path.join(jit.SHIPPED_ROOT, key)} ({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
