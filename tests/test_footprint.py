"""Issue 31's done-when measurements (studies/footprint.py): a 5 kg box's footprint in a deformable surface,
set back into it, and loaded twice as much. One run of the study, every criterion asserted on what it
measured. The run skips the two flat-surface references (``references=False``): they are only printed, no
criterion reads them, and they were a third of the study's mj_steps (4,400 of 13,200). The study runs on the
compiled backend (its default); tests/test_deform_compiled.py compares that with the numpy reference."""

import numpy as np
import pytest

from rft_mujoco.studies import footprint


@pytest.fixture(scope="module")
def result():
    return footprint.run(references=False)


def test_footprint_is_s1_deep_with_the_box_outline(result):
    s1 = result["s1"]
    assert 0.005 < s1 < 0.03                       # the box sank (loose glass beads, 4.9 kPa)
    assert abs(result["footprint_depth_min"] - s1) <= footprint.DEPTH_TOL
    assert abs(result["footprint_depth_max"] - s1) <= footprint.DEPTH_TOL
    assert result["outline_error"] <= result["cell"]


def test_volume_is_conserved(result):
    assert result["footprint_volume"] > 0.0
    assert abs(result["volume_change"]) <= footprint.VOLUME_TOL * result["footprint_volume"]
    assert result["berm_max"] > 0.0                # it went to a berm


def test_set_back_and_twice_the_load(result):
    s1 = result["s1"]
    assert result["s_back"] - s1 <= footprint.BACK_TOL * s1
    assert result["s_back"] - s1 >= 0.05 * s1         # the reload settled (a new loading cycle after the lift)
    assert abs(result["s2"] - result["s2_fresh"]) <= footprint.TWICE_TOL * result["s2_fresh"]
    assert result["s2"] > 1.5 * s1                 # twice the load did sink it further (virgin beyond the memory)
    assert all(footprint.checks(result).values())


def test_checks_fail_on_a_run_that_measured_nothing(result):
    empty = dict(result, s1=0.0, s_back=0.0, s2=0.0, s2_fresh=0.0, footprint_volume=0.0, volume_change=0.0,
                 footprint_depth_min=0.0, footprint_depth_max=0.0, outline_error=np.inf)
    assert not any(footprint.checks(empty).values())
