"""Issue 31: the sand wheel rig driven over its own track on a deformable surface (studies/ruts.py).

What the model gives (docs/deformable.md, "Ruts"): a rut about as deep as the wheel sank, kept from pass to
pass; with the memory rule (reloading to the stress already carried adds no plastic sinkage) the wheel's
sinkage in its own rut stays near the first pass's; it does not grow pass after pass as published multi-pass
tests do.

Two passes, not the study's default three: the second pass is the first one in the rut, so it is where a
broken memory rule (extra plastic sinkage on reloading) or a refilled rut shows. The third pass of the default
run changes nothing more (this VM, 2026-12-03, ``ruts.run(passes=3)``: sinkage 25.53, 25.36, 24.31 mm; rut
23.69, 23.95, 23.95 mm: the surface after pass 3 is the surface after pass 2) and cost a third of the test."""

import numpy as np

from rft_mujoco.studies import ruts


def test_a_second_pass_keeps_the_rut():
    r = ruts.run(passes=2)
    s, rut = np.array(r["sinkage"]), np.array(r["rut"])
    assert s.shape == rut.shape == (2,)
    assert s[0] > 0.005                                      # the first pass sank (30 N on loose glass beads)
    assert rut[0] > 0.5 * s[0]                               # and left a rut
    assert np.all(np.abs(s[1:] - s[0]) <= 0.15 * s[0])       # the memory: the pass in the rut as deep as the first
    assert np.all(np.diff(rut) >= -0.0005)                   # the rut is kept (not refilled)
