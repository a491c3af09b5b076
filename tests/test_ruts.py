"""Issue 31: the sand wheel rig driven three times over its own track on a deformable surface (studies/ruts.py).

What the model gives (docs/deformable.md, "Ruts"): a rut about as deep as the wheel sank, kept from pass to
pass; with the memory rule (reloading to the stress already carried adds no plastic sinkage) the wheel's
sinkage in its own rut stays near the first pass's; it does not grow pass after pass as published multi-pass
tests do."""

import numpy as np

from rft_mujoco.studies import ruts


def test_three_passes_keep_the_rut():
    r = ruts.run(passes=3)
    s, rut = np.array(r["sinkage"]), np.array(r["rut"])
    assert s[0] > 0.005                                      # the first pass sank (30 N on loose glass beads)
    assert rut[0] > 0.5 * s[0]                               # and left a rut
    assert np.all(np.abs(s[1:] - s[0]) <= 0.15 * s[0])       # the memory: later passes as deep as the first
    assert np.all(np.diff(rut) >= -0.0005)                   # the rut is kept (not refilled)
