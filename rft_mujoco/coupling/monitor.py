"""Validity monitor: tells the user (once) when a scene leaves the range where 3D-RFT is validated.

3D-RFT is a quasi-static, rate-independent model fitted to slow intrusions at moderate depth (Agarwal,
Goldman & Kamrin, PNAS 2023). Outside that range it still returns numbers; this monitor says so. Per loaded
body (at least one submerged leading element) it estimates:

* the macro-inertial number ``I_mac = v sqrt(rho_g / (xi_n L))``: inertial against frictional stress
  at the body scale; valid below :data:`I_MAC_MAX` = 0.15;
* the micro-inertial number ``I = gamma_dot d sqrt(rho_g / P)`` of the grains, with the estimates
  ``gamma_dot ~ v / L`` (shear rate: the body speed over its size) and ``P ~ xi_n max(z, d)`` (the RFT
  stress scale at the deepest loaded element's depth ``z``, but at least one grain deep: shallower, the
  continuum pressure estimate means nothing); valid below :data:`I_MICRO_MAX` = 0.01; needs
  ``Media.grain_diameter`` ``d`` (skipped when it is ``None``);
* the depth-to-size ratio ``z / L``; valid below :data:`DEPTH_RATIO_MAX` = 10;
* with the explicit solve, how often it stops a flowing body within a step (:meth:`ValidityMonitor.observe_flow`):
  a body it often stops is light for it, and the implicit solve is the one that gets it right (warned with
  :class:`rft_mujoco.SandSetupWarning`, not a limit of 3D-RFT).

Here ``v = |v_com| + R |omega|`` bounds the speed of the body's surface points (m/s), ``L = 2 R`` is the
diameter of the body's element bounding sphere (m), ``rho_g = Media.grain_density`` (kg/m^3) and
``xi_n = Media.xi_n_at(|g|)`` (N/m^3).

The check is cheap (a few array operations on the loaded bodies) and runs every
:data:`CHECK_EVERY` evaluations. It warns with :class:`RFTValidityWarning`, at most once per sand handle
for each reason (quasi-static regime, depth, light bodies), with the numbers; ``monitor.worst`` keeps the
largest values seen. The warning names the user's line (the first frame outside the library,
:func:`rft_mujoco.coupling.callers.user_stacklevel`: usually the ``mj_step`` call). The depth warning says
the body is sinking through the bed only when it is: its COM moves down along gravity faster than
:data:`SINKING_SPEED` and the sand does not hold it at rest (``Diagnostics.resting``); otherwise it says the
body is deeper than validated. Switch it off with ``attach(..., monitor=False)``; silence it with
``warnings.simplefilter("ignore", rft_mujoco.RFTValidityWarning)``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from rft_mujoco.coupling.callers import user_stacklevel
from rft_mujoco.geometry.elements import SandSetupWarning
from rft_mujoco.physics.law import gravity_direction
from rft_mujoco.physics.media import Media

I_MAC_MAX = 0.15
"""Largest macro-inertial number of the quasi-static regime (Agarwal et al. 2023)."""
I_MICRO_MAX = 0.01
"""Largest micro-inertial number of the quasi-static regime."""
DEPTH_RATIO_MAX = 10.0
"""Largest depth, in body sizes, of the validated range."""
CHECK_EVERY = 10
"""Evaluations between two checks (RK4 evaluates four times per step)."""
SINKING_SPEED = 1e-3
"""m/s: a deep body whose COM moves down along gravity faster than this, and that the sand does not hold at
rest, is sinking (the rest speed of the stability and load-path studies)."""


LIGHT_SCALE = 0.9
"""A flowing body whose explicit flow wrench was scaled below this fraction of the law's (``Diagnostics.scale``:
so as not to reverse its motion) was stopped by the sand within the step."""
LIGHT_SHARE = 0.3
"""Warn that bodies are light for the explicit solve when the sand stops their flow within the step (scale below
:data:`LIGHT_SCALE`) at more than this share of the checks that saw them flow. Measured 2026-12-04: the bundled
swimmer at the animal's 22 g 0.34-0.46 per link (the serpenoid at 0.5 rad, 1 Hz, dt 2 ms, 5 mm elements) and
0.72 (random actions), at 100x 0-0.03 and 0.02; with random actions (300 env steps, every flowing body)
SandAnt-v0 0.20, SandHalfCheetah-v0 0.13, the other tasks below 0.02."""
LIGHT_SAMPLES = 50
"""Checks in flow a body needs before the share of :data:`LIGHT_SHARE` is judged."""


class RFTValidityWarning(UserWarning):
    """A sand scene left the range where 3D-RFT is validated (quasi-static, at most ~10 body sizes deep)."""


def validity_numbers(speed, length, depth, media: Media, gravity: float = 9.81):
    """Macro-inertial number, micro-inertial number and depth-to-size ratio (all dimensionless).

    Args:
        speed: (n,) m/s, speed scale of each body (surface points).
        length: (n,) m, size of each body.
        depth: (n,) m, depth of each body's deepest loaded element.
        media: the granular medium (``grain_density``; ``grain_diameter`` for the micro number).
        gravity: |g| in m/s^2.
    Returns:
        i_mac (n,), i_micro (n,) (NaN where the grain diameter is unknown or the depth is 0; the
        pressure is taken at least one grain deep),
        depth_ratio (n,).
    """
    speed = np.asarray(speed, dtype=float)
    length = np.asarray(length, dtype=float)
    depth = np.asarray(depth, dtype=float)
    xi_n = media.xi_n_at(gravity)
    rho_g = media.grain_density
    i_mac = speed * np.sqrt(rho_g / (xi_n * length))
    if media.grain_diameter is None:
        i_micro = np.full(speed.shape, np.nan)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            pressure = xi_n * np.maximum(depth, media.grain_diameter)
            i_micro = np.where(depth > 0.0, speed / length * media.grain_diameter
                               * np.sqrt(rho_g / pressure), np.nan)
    return i_mac, i_micro, depth / length


class ValidityMonitor:
    """Checks one sand handle's loaded bodies every ``every`` evaluations; warns once per reason.

    Attributes:
        every: evaluations between checks.
        worst: largest values seen: ``{"i_mac": (value, body, time_s), "i_micro": ..., "depth_ratio": ...}``.
        warned: the reasons already warned about (``"quasi-static"``, ``"depth"``, ``"light"``).
        flow_checks: per body name, [checks that saw it flow, of which the explicit solve stopped it within the
            step] (:meth:`observe_flow`).
    """

    def __init__(self, every: int = CHECK_EVERY):
        self.every = every
        self.reset()

    @property
    def every(self) -> int:
        return self._every

    @every.setter
    def every(self, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"every must be a positive int (evaluations between checks), got {value!r}")
        self._every = int(value)
        from rft_mujoco.coupling.dispatch import DISPATCHER      # native routes read the period: rebuild
        DISPATCHER.invalidate()

    def reset(self) -> None:
        """Forget the worst values and the warnings already given (warn again on the next violation)."""
        self.worst: dict[str, tuple[float, str, float]] = {}
        self.warned: set[str] = set()
        self.flow_checks: dict[str, list[int]] = {}     # body: [checks in flow, of which stopped within the step]

    def observe(self, names, speed, length, depth, media: Media, gravity: float, time: float, *,
                sinking=None, stacklevel: int | None = None) -> None:
        """Check bodies (lists/arrays over the loaded bodies) and warn if one is outside the valid range.

        ``sinking``: (n,) bool, which bodies are sinking (moving down, not held at rest), or None
        (unknown): the depth warning says "sinking" only for a body marked True. ``stacklevel`` is passed
        to :func:`warnings.warn`; None (default) names the first frame outside the library.
        """
        if len(names) == 0:
            return
        if stacklevel is None:
            stacklevel = user_stacklevel()
        i_mac, i_micro, ratio = validity_numbers(speed, length, depth, media, gravity)
        for key, values in (("i_mac", i_mac), ("i_micro", i_micro), ("depth_ratio", ratio)):
            if np.all(np.isnan(values)):
                continue
            j = int(np.nanargmax(values))
            if key not in self.worst or values[j] > self.worst[key][0]:
                self.worst[key] = (float(values[j]), names[j], float(time))
        fast = (i_mac > I_MAC_MAX) | (np.nan_to_num(i_micro) > I_MICRO_MAX)
        if fast.any() and "quasi-static" not in self.warned:
            j = int(np.flatnonzero(fast)[np.argmax(i_mac[fast])])
            self.warned.add("quasi-static")
            micro = ("n/a (media.grain_diameter unknown)" if math.isnan(i_micro[j]) else
                     f"{i_micro[j]:.3g} (limit {I_MICRO_MAX}; d = {media.grain_diameter:g} m, "
                     f"P ~ xi_n max(z, d) = {media.xi_n_at(gravity) * max(depth[j], media.grain_diameter):.3g} Pa)")
            warnings.warn(
                f"3D-RFT is outside its quasi-static range on body {names[j]!r} at t = {time:.4g} s: "
                f"macro-inertial number I_mac = {i_mac[j]:.3g} (limit {I_MAC_MAX}; v = {speed[j]:.3g} m/s, "
                f"L = {length[j]:.3g} m, rho_g = {media.grain_density:g} kg/m^3, "
                f"xi_n = {media.xi_n_at(gravity):.3g} N/m^3), micro-inertial number I = {micro}. "
                "The forces are extrapolated (inertial effects of the grains are missing); slow the body "
                "down to stay in the validated range. Warned once per sand handle; "
                "handle.monitor.worst keeps the largest values.", RFTValidityWarning, stacklevel=stacklevel)
        deep = ratio > DEPTH_RATIO_MAX
        if deep.any() and "depth" not in self.warned:
            j = int(np.flatnonzero(deep)[np.argmax(ratio[deep])])
            self.warned.add("depth")
            if sinking is not None and bool(np.asarray(sinking)[j]):
                why = ("The body is sinking through the bed (moving down, not held at rest by the sand): "
                       "probably too heavy for this medium.")
            else:
                why = "The body is deeper than validated; the forces there are extrapolated."
            warnings.warn(
                f"3D-RFT is outside its validated depth range on body {names[j]!r} at t = {time:.4g} s: "
                f"depth {depth[j]:.3g} m is {ratio[j]:.3g} body sizes (limit {DEPTH_RATIO_MAX}; "
                f"L = {length[j]:.3g} m). The linear depth scaling of RFT is not validated that deep. "
                f"{why} Warned once per sand handle; handle.monitor.worst keeps the largest values.",
                RFTValidityWarning, stacklevel=stacklevel)

    def check(self, handle, data, rows, v_com, omega, max_depth) -> None:
        """Observe the candidate bodies ``rows`` (indices into ``handle.body_ids``) of one evaluation.

        Args:
            handle: the :class:`rft_mujoco.SandHandle` (its diagnostics of ``data`` tell which bodies rest).
            data: its MjData (for the time).
            rows: (k,) int, candidate rows; v_com, omega: (k, 3) m/s, rad/s, the bodies' velocities at the
                start of the evaluation; max_depth: (k,) m.
        """
        loaded = np.flatnonzero(np.asarray(max_depth) > 0.0)
        if loaded.size == 0:
            return
        r = np.asarray(rows)[loaded]
        radius = handle.layout.bound_radius[r]
        v = np.asarray(v_com)[loaded]
        speed = np.linalg.norm(v, axis=1) + radius * np.linalg.norm(np.asarray(omega)[loaded], axis=1)
        names = [handle.body_names[i] for i in r]
        g_hat, g_mag = gravity_direction(handle.model.opt.gravity)
        diag = handle.diagnostics(data)
        sinking = (v @ g_hat > SINKING_SPEED) & ~np.asarray(diag.resting, dtype=bool)[r]
        self.observe(names, speed, 2.0 * radius, np.asarray(max_depth)[loaded], handle.media, g_mag,
                     float(data.time), sinking=sinking)
        if handle.stabilize and handle.solve == "explicit":
            flowing = ~np.asarray(diag.resting, dtype=bool)[r]
            self.observe_flow([n for n, f in zip(names, flowing) if f], np.asarray(diag.scale)[r][flowing],
                              float(handle.model.opt.timestep))

    def observe_flow(self, names, scale, timestep: float, *, stacklevel: int | None = None) -> None:
        """Count the explicit solve's flowing bodies ``names`` whose wrench was scaled (``scale`` (n,), the
        applied over the law's) below :data:`LIGHT_SCALE`; warn (:class:`rft_mujoco.SandSetupWarning`, once) when
        such stops are more than :data:`LIGHT_SHARE` of a body's checks in flow (at least :data:`LIGHT_SAMPLES`):
        the body is light for the explicit solve at ``timestep`` (s), whose answer then misses the quasi-static
        one (docs/rest.md, "Any mass")."""
        for name, value in zip(names, scale):
            counts = self.flow_checks.setdefault(name, [0, 0])
            counts[0] += 1
            counts[1] += int(value < LIGHT_SCALE)
        light = sorted(((c[1] / c[0], n) for n, c in self.flow_checks.items()
                        if c[0] >= LIGHT_SAMPLES and c[1] > LIGHT_SHARE * c[0]), reverse=True)
        if light and "light" not in self.warned:
            self.warned.add("light")
            listed = ", ".join(f"{n!r} ({share:.0%} of {self.flow_checks[n][0]})" for share, n in light[:6])
            warnings.warn(
                f"rft_mujoco: the explicit sand solve stops these bodies' flow within a step in many of the checks "
                f"that saw them flow: {listed} (their wrench scaled below {LIGHT_SCALE:g} of the law's so as not "
                f"to reverse their motion, Diagnostics.scale). They are light for it at dt = {timestep:g} s, and "
                "its answer then misses the quasi-static one (the bundled swimmer at its real 22 g swims 2-3x too "
                "fast with it). Do: attach(..., solve='implicit') (docs/rest.md, 'Any mass'), or filter "
                "SandSetupWarning if that error is acceptable. Warned once per sand handle; "
                "handle.monitor.flow_checks keeps the counts.", SandSetupWarning,
                stacklevel=user_stacklevel() if stacklevel is None else stacklevel)
