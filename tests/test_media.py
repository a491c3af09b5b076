"""Granular media: xi_n against the paper's checkpoints, presets, validation and the registry.

Golden values: Agarwal, Goldman & Kamrin, PNAS 120 (2023) e2214017120, as restated in
../shared/reference/3d-rft.md: ``xi_n = rho_c |g| f_hat(mu_int)``, ``f_hat(mu) = 894 mu^3 - 386 mu^2 +
89 mu``; (rho_c, mu_int) = (3000, 0.4) gives xi_n ~ 0.92e6 N/m^3 (the paper quotes two digits, so 1%),
(1310, 0.21) gives ~0.12e6 N/m^3 (one significant digit of rounding, so 10%).
"""

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rft_mujoco.physics import media
from rft_mujoco.physics.media import (DEM_GLASS_BEADS, LI_LOOSE_GLASS_BEADS, MALADEN_GLASS_BEADS, MPM_VALIDATION,
                              PRESETS, Media, f_hat, get_media)


# --- xi_n and f_hat --------------------------------------------------------------------------------
def test_f_hat_values():
    # f_hat(0.4) = 894*0.064 - 386*0.16 + 89*0.4 = 57.216 - 61.76 + 35.6
    assert f_hat(0.4) == pytest.approx(31.056, rel=1e-12)
    # f_hat(0.21) = 894*0.009261 - 386*0.0441 + 89*0.21 = 8.279334 - 17.0226 + 18.69
    assert f_hat(0.21) == pytest.approx(9.946734, rel=1e-12)
    assert f_hat(0.0) == 0.0


def test_xi_n_checkpoint_mpm():
    xi = Media(3000.0, 0.4).xi_n
    assert xi == pytest.approx(0.92e6, rel=0.01)
    assert xi == pytest.approx(3000.0 * 9.81 * 31.056, rel=1e-12)


def test_xi_n_checkpoint_dem():
    xi = Media(1310.0, 0.21).xi_n
    assert xi == pytest.approx(0.12e6, rel=0.10)
    assert xi == pytest.approx(1310.0 * 9.81 * 9.946734, rel=1e-12)


def test_xi_n_uses_standard_gravity_and_scales_with_gravity():
    m = MPM_VALIDATION
    assert media.STANDARD_GRAVITY == 9.81
    assert m.xi_n == m.xi_n_at(9.81)
    assert m.xi_n_at(2 * 9.81) == pytest.approx(2 * m.xi_n, rel=1e-14)
    assert m.xi_n_at(1.62) == pytest.approx(m.xi_n * 1.62 / 9.81, rel=1e-14)   # the Moon


@pytest.mark.parametrize("bad", [0.0, -9.81, math.nan, math.inf])
def test_xi_n_at_rejects_bad_gravity(bad):
    with pytest.raises(ValueError, match="gravity") as info:
        MPM_VALIDATION.xi_n_at(bad)
    assert repr(bad) in str(info.value)


@settings(max_examples=100, deadline=None)
@given(rho=st.floats(1000.0, 5000.0), k=st.floats(0.1, 2.0))
def test_xi_n_is_linear_in_density(rho, k):
    assert Media(rho * k, 0.4).xi_n == pytest.approx(k * Media(rho, 0.4).xi_n, rel=1e-12)


# --- presets ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("preset, rho_c, mu_int, mu_surf", [
    (MPM_VALIDATION, 3000.0, 0.4, 0.4),
    (DEM_GLASS_BEADS, 1310.0, 0.21, 0.21),
    (LI_LOOSE_GLASS_BEADS, 1450.0, 0.4, 0.4),
    (MALADEN_GLASS_BEADS, 1500.0, 0.4, 0.27),
])
def test_preset_values(preset, rho_c, mu_int, mu_surf):
    assert (preset.rho_c, preset.mu_int, preset.mu_surf) == (rho_c, mu_int, mu_surf)
    assert PRESETS[preset.name] is preset
    assert get_media(preset.name) is preset


def test_presets_registry_is_complete():
    assert set(PRESETS) == {"mpm_validation", "dem_glass_beads", "li_loose_glass_beads", "maladen_glass_beads"}


def test_dem_preset_is_fully_rough_by_default():
    # built with mu_surf=None: fully rough means mu_surf = mu_int
    assert DEM_GLASS_BEADS.mu_surf == DEM_GLASS_BEADS.mu_int == 0.21
    assert Media(1500.0, 0.3).mu_surf == 0.3
    assert isinstance(Media(1500.0, 0.3).mu_surf, float)


def test_media_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        MPM_VALIDATION.rho_c = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        MPM_VALIDATION.mu_surf = 0.1
    assert MPM_VALIDATION.rho_c == 3000.0


def test_replace_returns_validated_copy():
    m = MPM_VALIDATION.replace(mu_surf=0.1)
    assert m.mu_surf == 0.1 and MPM_VALIDATION.mu_surf == 0.4
    with pytest.raises(ValueError, match="0.9"):
        MPM_VALIDATION.replace(mu_surf=0.9)


# --- validation ------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, bad", [
    (dict(rho_c=math.nan, mu_int=0.4), "nan"),
    (dict(rho_c=math.inf, mu_int=0.4), "inf"),
    (dict(rho_c=-1500.0, mu_int=0.4), "-1500.0"),
    (dict(rho_c=0.0, mu_int=0.4), "0.0"),
    (dict(rho_c=1500.0, mu_int=math.nan), "nan"),
    (dict(rho_c=1500.0, mu_int=1.5), "1.5"),
    (dict(rho_c=1500.0, mu_int=-0.3), "-0.3"),
    (dict(rho_c=1500.0, mu_int=0.4, mu_surf=0.55), "0.55"),      # mu_surf > mu_int
    (dict(rho_c=1500.0, mu_int=0.4, mu_surf=-0.1), "-0.1"),
    (dict(rho_c=1500.0, mu_int=0.4, mu_surf=math.inf), "inf"),
    (dict(rho_c=1500.0, mu_int=0.4, grain_diameter=-3e-4), "-0.0003"),
    (dict(rho_c=1500.0, mu_int=0.4, grain_density=math.nan), "nan"),
])
def test_invalid_media_raise_with_the_bad_value(kwargs, bad):
    with pytest.raises(ValueError) as info:
        Media(**kwargs)
    assert bad in str(info.value)


def test_mu_surf_above_mu_int_message_explains():
    with pytest.raises(ValueError, match="mu_int"):
        Media(1500.0, 0.3, 0.31)


def test_mu_surf_zero_and_equal_to_mu_int_are_allowed():
    assert Media(1500.0, 0.3, 0.0).mu_surf == 0.0
    assert Media(1500.0, 0.3, 0.3).mu_surf == 0.3


# --- registry --------------------------------------------------------------------------------------
def test_get_media_passes_media_through():
    m = Media(1600.0, 0.5, 0.2)
    assert get_media(m) is m


def test_get_media_unknown_name_lists_valid_names():
    with pytest.raises(ValueError) as info:
        get_media("beach_sand")
    msg = str(info.value)
    assert "beach_sand" in msg
    for name in PRESETS:
        assert name in msg
