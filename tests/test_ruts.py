"""Issue 31: the sand wheel rig driven three times over its own track on a deformable surface (studies/ruts.py)
sinks further each pass, by less each time, and leaves a rut."""

import numpy as np

from rft_mujoco.studies import ruts


def test_three_passes_sink_more_by_less():
    r = ruts.run(passes=3)
    s = np.array(r["sinkage"])
    steps = np.diff(np.concatenate([[0.0], s]))
    assert s[0] > 0.005                                 # the first pass sank (30 N on loose glass beads)
    assert np.all(steps > 0.0)                          # every pass sinks further ...
    assert np.all(np.diff(steps) < 0.0)                 # ... by less than the pass before
    rut = np.array(r["rut"])
    assert np.all(np.diff(rut) > 0.0) and rut[0] > 0.5 * s[0]      # the rut deepens with the wheel
