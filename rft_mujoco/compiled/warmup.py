"""Compile (or load from the cache) the coupling's kernels: the native route's two phases, which contain the
evaluation of every terrain and setting (a route over no handle on a tiny model), and the native callbacks.

Compiled at their first use instead: the Python path's phases (:func:`rft_mujoco.compiled.evaluate.broadphase`,
:func:`~rft_mujoco.compiled.evaluate.evaluate`; the dispatcher runs the native route from a model's first
evaluation on, and the Python path only with observers, after an error or where the route cannot be
built) and :func:`rft_mujoco.compiled.law.element_forces`. The progress line reports those compiles too."""

from __future__ import annotations

import mujoco

from rft_mujoco.compiled import route

_MODEL = """<mujoco><worldbody>
  <body name="a" pos="0 0 0.01"><freejoint/><geom type="sphere" size="0.03" mass="1"/>
    <body name="b" pos="0.04 0 0"><joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.1"/></body></body>
  <geom type="box" pos="0.3 0 0" size="0.02 0.02 0.02"/>
</worldbody></mujoco>"""


def run() -> None:
    model = mujoco.MjModel.from_xml_string(_MODEL)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    try:
        route.warm_up(model, data)
    except RuntimeError:                             # no route here (route.efc_layout): the Python path runs
        pass
    from rft_mujoco.compiled import native  # noqa: F401  (compiles the native callbacks)
