"""The exposed-surface rule against the brute-force reference of rft_mujoco.studies.overlap (issue #16)."""

import numpy as np
import pytest

from rft_mujoco.studies import overlap


@pytest.mark.parametrize("name", ["hinge_45", "hinge_135", "foot_in_calf", "swimmer", "quadruped_leg"])
def test_culling_equals_the_brute_force_rule_at_the_same_element_size(name):
    """At one element size the coupling (static culling inside a weld group, run-time culling against other
    bodies' geoms, bounding-sphere shortcuts) drops exactly the elements whose centroid is inside another
    geom: the same force and exposed area as the brute-force reference, to round-off."""
    case = overlap.CASES[name]
    model = overlap._model(case)
    data = overlap._posed(case, model)
    ids = overlap._body_ids(case, model)
    z = max(float(data.xpos[b][2]) for b in ids) + overlap.DEPTH
    size = 0.006
    for dofs, speeds in case.motions.values():
        omega = overlap.spin(model, data, ids[0], dofs, speeds)
        f_ref, exposed_ref, whole = overlap.reference(model, data, ids, omega, size, z)
        f, exposed = overlap.library(model, data, ids, dofs, speeds, cull=True, surface_z=z, resolution=size)
        np.testing.assert_allclose(f, f_ref, rtol=1e-9, atol=1e-9 * np.abs(f_ref).max())
        assert exposed == pytest.approx(exposed_ref, rel=1e-9)
        assert exposed < 0.95 * whole                                   # the case has hidden surface


def test_default_resolution_is_close_to_the_converged_exposed_surface():
    """At the default element size, against the 1 mm reference: capsules meeting at a hinge and the
    quadruped's leg within 2%; without culling the same scenes get 7-27% too much force."""
    rows = overlap.run(["hinge_0", "hinge_90", "quadruped_leg"])
    assert all(r["error"] < 0.02 for r in rows), [(r["case"], r["motion"], r["error"]) for r in rows]
    assert all(r["overcount"] > 1.07 for r in rows)
    lines = overlap.table_lines(rows)
    assert len(lines) == 2 + len(rows) and "err culled" in lines[0]
