"""Issue 31: the sand wheel rig driven three times over the same track on a deformable surface (studies/ruts.py).

What the model gives (docs/deformable.md, "Ruts"): the wheel sinks deeper pass after pass, by less each pass
(each reload settles by a plastic increment that shrinks with the loading cycles, and the rut's slumped walls
are loose sand that the wheel presses out again), and the rut is kept. On the compiled backend (the study's
default; tests/test_deform_compiled.py compares it with the numpy reference)."""

import numpy as np

from rft_mujoco.studies import ruts


def test_three_passes_sink_deeper_by_diminishing_increments():
    r = ruts.run(passes=3)
    s, rut = np.array(r["sinkage"]), np.array(r["rut"])
    assert s[0] > 0.005                                      # the first pass sank (30 N on loose glass beads)
    assert rut[0] > 0.5 * s[0]                               # and left a rut
    inc = np.diff(s)
    assert np.all(inc > 0.0005)                              # each pass sinks deeper, ...
    assert inc[1] < 0.75 * inc[0]                            # ... by less than the one before
    assert np.all(np.diff(rut) >= -0.0005)                   # the rut is kept (not refilled)
