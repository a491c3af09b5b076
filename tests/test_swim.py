"""The sand-swimming study (rft_mujoco.studies.swim): wave geometry, one kinematic run each way, the CLI."""

import math

import numpy as np
import pytest

from rft_mujoco.studies import swim


def test_wave_shape_covers_the_study_range():
    ratios = [swim.wave_shape(a)[0] for a in swim.AMPLITUDES]
    assert ratios[0] < 0.06 and max(ratios) > 0.38          # A/lambda 0.05 ... 0.4, as the issue asks
    assert np.all(np.diff(ratios) > 0)                        # the sweep is ordered in A/lambda
    ratio, lam, length = swim.wave_shape(1e-6)
    assert ratio < 1e-5 and lam == pytest.approx(length, rel=1e-6)   # straight: lambda is the body


def test_a_travelling_wave_swims_forward_and_culling_changes_it():
    on = swim.swim(0.9, 1.0, cycles=3)
    off = swim.swim(0.9, 1.0, cycles=3, cull=False)
    assert 0.05 < on["eta"] < 1.0 and on["speed_mps"] > 0.0
    assert on["tracking_rms_rad"] < 0.1 * 0.9                 # kinematic driving: within 10% of the amplitude
    assert abs(on["yaw_drift_rad"]) < 0.1
    assert not math.isclose(on["eta"], off["eta"], rel_tol=1e-3)


def test_swim_cli_help(capsys):
    from rft_mujoco.studies import cli

    with pytest.raises(SystemExit):
        cli.main(["swim", "--help"])
    assert "--quick" in capsys.readouterr().out
