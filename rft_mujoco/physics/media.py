"""Granular media: the material parameters 3D-RFT needs, and presets from the literature.

The stress scale of 3D-RFT is ``xi_n = rho_c * |g| * f_hat(mu_int)`` in N/m^3 (Agarwal, Goldman & Kamrin,
PNAS 2023, eq. 4), with the cubic fit ``f_hat(mu) = 894 mu^3 - 386 mu^2 + 89 mu``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

STANDARD_GRAVITY = 9.81
"""|g| in m/s^2 used by :attr:`Media.xi_n` (the paper's value)."""

MU_INT_RANGE = (0.05, 1.0)
"""Allowed internal friction coefficients (the f_hat fit was made for dry media well inside this range)."""

RHO_C_RANGE = (100.0, 20000.0)
"""Allowed bulk (critical-state) densities in kg/m^3."""


def f_hat(mu_int: float) -> float:
    """The paper's cubic fit of the dimensionless stress scale against internal friction (-)."""
    return 894.0 * mu_int**3 - 386.0 * mu_int**2 + 89.0 * mu_int


def _check_range(name: str, value: float, low: float, high: float, hint: str) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (
            math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{name} must be a finite number in [{low}, {high}], got {value!r}. {hint}")


@dataclasses.dataclass(frozen=True)
class Media:
    """A dry, cohesionless granular medium as 3D-RFT sees it.

    Attributes:
        rho_c: bulk (critical-state) density of the packed medium, kg/m^3.
        mu_int: internal friction coefficient of the medium, dimensionless.
        mu_surf: friction coefficient between the intruder surface and the grains, dimensionless,
            ``0 <= mu_surf <= mu_int``. ``None`` (the default) means a fully rough surface,
            ``mu_surf = mu_int``.
        grain_diameter: mean grain diameter in m, used only by the validity monitor (micro-inertial
            number); ``None`` if unknown.
        grain_density: density of the grain material in kg/m^3 (2500 for glass, 2650 for quartz sand),
            used only by the validity monitor.
        name: a label for tables and plots.
    """

    rho_c: float
    mu_int: float
    mu_surf: float | None = None
    grain_diameter: float | None = None
    grain_density: float = 2500.0
    name: str = "custom"

    def __post_init__(self) -> None:
        _check_range("rho_c (kg/m^3)", self.rho_c, *RHO_C_RANGE,
                     "Use the bulk density of the packed medium, e.g. 1300-1800 for dry sand or beads.")
        _check_range("mu_int", self.mu_int, *MU_INT_RANGE,
                     "Typical dry sands and glass beads have mu_int between 0.2 and 0.8.")
        if self.mu_surf is None:
            object.__setattr__(self, "mu_surf", float(self.mu_int))
        _check_range("mu_surf", self.mu_surf, 0.0, self.mu_int,
                     "The intruder-grain friction cannot exceed the medium's internal friction mu_int; "
                     "a fully rough surface has mu_surf = mu_int.")
        if self.grain_diameter is not None:
            _check_range("grain_diameter (m)", self.grain_diameter, 1e-6, 0.1,
                         "Give the mean grain diameter in metres (0.3 mm sand is 3e-4).")
        _check_range("grain_density (kg/m^3)", self.grain_density, 100.0, 20000.0,
                     "Glass is 2500, quartz 2650.")

    @property
    def xi_n(self) -> float:
        """Stress scale rho_c * |g| * f_hat(mu_int) in N/m^3 at standard gravity (9.81 m/s^2)."""
        return self.xi_n_at(STANDARD_GRAVITY)

    def xi_n_at(self, gravity: float) -> float:
        """Stress scale in N/m^3 for a gravitational acceleration of magnitude ``gravity`` (m/s^2)."""
        if not (math.isfinite(gravity) and gravity > 0):
            raise ValueError(f"gravity magnitude must be finite and > 0 m/s^2, got {gravity!r}; "
                             "3D-RFT stresses are hydrostatic and vanish without gravity.")
        return self.rho_c * gravity * f_hat(self.mu_int)

    def replace(self, **changes) -> "Media":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


# --- presets --------------------------------------------------------------------------------------
MPM_VALIDATION = Media(3000.0, 0.4, 0.4, name="mpm_validation")
"""The continuum (MPM) medium the paper validates 3D-RFT against (Agarwal et al. 2023, Figs. 2-3):
rho_c = 3000 kg/m^3, mu_int = mu_surf = 0.4; xi_n ~ 0.92e6 N/m^3."""

DEM_GLASS_BEADS = Media(1310.0, 0.21, None, grain_diameter=3e-3, grain_density=2500.0,
                        name="dem_glass_beads")
"""The DEM glass-bead bed of the paper's drilling experiments (Agarwal et al. 2023, cylinder and bunny
drills): rho_c = 1310 kg/m^3, mu_int = 0.21, fully rough (mu_surf = 0.21); xi_n ~ 0.12e6 N/m^3.
The 3 mm grain size is this project's assumption, used only by the validity monitor."""

LI_LOOSE_GLASS_BEADS = Media(1450.0, 0.4, 0.4, grain_diameter=3e-3, grain_density=2500.0,
                             name="li_loose_glass_beads")
"""Loosely packed 3 mm glass beads of Li, Zhang & Goldman, Science 339 (2013) 1408, with the
(rho_c, mu_int, mu_surf) = (1450, 0.4, 0.4) that Agarwal et al. 2023 use to compare with 2D RFT."""

MALADEN_GLASS_BEADS = Media(1500.0, 0.4, 0.27, grain_diameter=3e-4, grain_density=2500.0,
                            name="maladen_glass_beads")
"""0.3 mm glass beads of Maladen et al., Science 325 (2009) 314 (sandfish swimming), with the
(rho_c, mu_int, mu_surf) = (1500, 0.4, 0.27) used in Agarwal et al. 2023."""

PRESETS: dict[str, Media] = {m.name: m for m in
                             (MPM_VALIDATION, DEM_GLASS_BEADS, LI_LOOSE_GLASS_BEADS, MALADEN_GLASS_BEADS)}


def get_media(name: str | Media) -> Media:
    """A preset by name (or a :class:`Media` passed through)."""
    if isinstance(name, Media):
        return name
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown media preset {name!r}; valid names: {sorted(PRESETS)}, "
                         "or pass rft_mujoco.Media(rho_c, mu_int, mu_surf).") from None
