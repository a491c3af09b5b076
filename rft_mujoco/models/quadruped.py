"""The bundled quadruped (``quadruped.xml``): its leg, actuator and foot names in model order, and its scripted
gaits (pure numpy, no MuJoCo).

A gait is a foot trajectory per leg, in the leg's hip frame, turned into joint angles by the analytic
inverse kinematics of the leg (:func:`leg_ik`). Targets come in actuator order (:data:`ACTUATOR_NAMES`):
``FL_hip FL_thigh FL_calf FR_hip ... RR_calf``, in rad, for the model's position servos.

Leg frame and joint conventions (those of the model; x forward, y left, z up, trunk-aligned):

- hip (abduction) joint about x at the hip; the thigh plane sits ``hip_offset_m`` outboard of it
  (+y for left legs, -y for right legs);
- thigh (flexion) joint about y; positive angles swing the foot backward;
- calf (knee) joint about y, negative (knee points backward).

Example::

    xml = importlib.resources.files("rft_mujoco.models") / "quadruped.xml"
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    gait = TrotGait.from_model(model, frequency_hz=2.5, stride_m=0.10, step_height_m=0.06)
    data.ctrl[:] = gait.stand()             # (12,) rad
    data.ctrl[:] = gait.targets(data.time)  # each step; ~0.49 m/s on the rigid floor

``TrotGait.from_model`` also reads the robot's weight and servo gains for the load compensation and
velocity lead (see :class:`TrotGait`); a plain ``TrotGait(...)`` has both off and trots about half as fast.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

LEGS = ("FL", "FR", "RL", "RR")
"""Leg prefixes in actuator order: front-left, front-right, rear-left, rear-right."""

ACTUATOR_NAMES = tuple(f"{leg}_{joint}" for leg in LEGS for joint in ("hip", "thigh", "calf"))
"""The model's 12 actuators in order; each drives the joint of the same name + ``_joint``."""

FOOT_BODIES = tuple(f"{leg}_foot" for leg in LEGS)
"""Names of the foot bodies (a sphere each, welded to the calf), the bodies that touch the ground."""

SIDE = np.array([1.0, -1.0, 1.0, -1.0])
"""(4,) +1 for left legs, -1 for right legs, in :data:`LEGS` order."""
SIDE.flags.writeable = False

TROT_PHASE = np.array([0.0, 0.5, 0.5, 0.0])
"""(4,) phase offsets (fraction of a cycle) of the trot: diagonal pairs FL+RR and FR+RL alternate."""

TROT_PHASE.flags.writeable = False

_LEAD_DT_S = 1e-4
"""Half-width (s) of the central difference that gives the joint velocities of the velocity lead."""


@dataclasses.dataclass(frozen=True)
class LegGeometry:
    """Link lengths of one leg (all four legs are equal, mirrored left/right).

    Attributes:
        thigh_length_m: hip-flexion axis to knee axis, m.
        calf_length_m: knee axis to foot-sphere centre, m.
        hip_offset_m: lateral distance from the abduction axis to the thigh plane, m (positive; left
            legs are offset to +y, right legs to -y).
        foot_radius_m: radius of the foot sphere, m (foot centre height above the ground in stance).
    """

    thigh_length_m: float = 0.213
    calf_length_m: float = 0.213
    hip_offset_m: float = 0.08
    foot_radius_m: float = 0.02

    def __post_init__(self) -> None:
        for name in ("thigh_length_m", "calf_length_m", "hip_offset_m", "foot_radius_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be a finite length >= 0, got {value!r}")
        if self.thigh_length_m <= 0 or self.calf_length_m <= 0:
            raise ValueError(f"link lengths must be > 0, got thigh {self.thigh_length_m!r} m and "
                             f"calf {self.calf_length_m!r} m")

    @classmethod
    def from_model(cls, model) -> "LegGeometry":
        """Read the leg geometry from a compiled MjModel of the bundled quadruped (body names
        ``{leg}_thigh``, ``{leg}_calf``, ``{leg}_foot``). Raises ValueError if the legs differ."""
        rows = []
        for leg in LEGS:
            try:
                thigh = model.body(f"{leg}_thigh").pos
                calf = model.body(f"{leg}_calf").pos
                foot_body = model.body(f"{leg}_foot")
            except KeyError as err:
                raise ValueError(f"the model has no body {err}; expected the bundled quadruped's bodies "
                                 f"{leg}_thigh, {leg}_calf and {leg}_foot") from None
            foot_geom = int(model.body_geomadr[foot_body.id])
            rows.append((abs(thigh[1]), -calf[2], -foot_body.pos[2], model.geom_size[foot_geom, 0]))
        rows = np.array(rows)
        if not np.allclose(rows, rows[0], atol=1e-9):
            raise ValueError(f"legs are not identical: (hip offset, thigh, calf, foot radius) per leg "
                             f"{LEGS} = {rows.tolist()}")
        offset, thigh, calf, radius = rows[0]
        return cls(thigh_length_m=float(thigh), calf_length_m=float(calf), hip_offset_m=float(offset),
                   foot_radius_m=float(radius))


def leg_fk(q: np.ndarray, side: np.ndarray, geometry: LegGeometry = LegGeometry()) -> np.ndarray:
    """Foot-centre positions of legs in their hip frames (forward kinematics).

    Args:
        q: (..., 3) rad, (hip, thigh, calf) joint angles.
        side: (...,) +1 for a left leg, -1 for a right leg (broadcast against ``q[..., 0]``).
        geometry: the leg's link lengths.

    Returns:
        (..., 3) m, foot centre relative to the hip joint, trunk-aligned axes.
    """
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (3,):
        raise ValueError(f"q must have shape (..., 3), got {q.shape}")
    q0, q1, q2 = q[..., 0], q[..., 1], q[..., 2]
    l1, l2 = geometry.thigh_length_m, geometry.calf_length_m
    x = -l1 * np.sin(q1) - l2 * np.sin(q1 + q2)
    h = l1 * np.cos(q1) + l2 * np.cos(q1 + q2)          # downward extent in the leg plane
    d = np.asarray(side, dtype=float) * geometry.hip_offset_m
    y = d * np.cos(q0) + h * np.sin(q0)                 # rotate (d, -h) about x by q0
    z = d * np.sin(q0) - h * np.cos(q0)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def leg_jacobian(q: np.ndarray, side: np.ndarray, geometry: LegGeometry = LegGeometry()) -> np.ndarray:
    """Jacobian of :func:`leg_fk`: d(foot position in the hip frame)/d(joint angles).

    Args:
        q: (..., 3) rad, (hip, thigh, calf) joint angles.
        side: (...,) +1 for a left leg, -1 for a right leg.
        geometry: the leg's link lengths.

    Returns:
        (..., 3, 3) m/rad; ``J[..., i, j] = d foot_i / d q_j``.
    """
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (3,):
        raise ValueError(f"q must have shape (..., 3), got {q.shape}")
    q0, q1, q2 = q[..., 0], q[..., 1], q[..., 2]
    l1, l2 = geometry.thigh_length_m, geometry.calf_length_m
    s0, c0 = np.sin(q0), np.cos(q0)
    x = -l1 * np.sin(q1) - l2 * np.sin(q1 + q2)
    h = l1 * np.cos(q1) + l2 * np.cos(q1 + q2)
    d = np.asarray(side, dtype=float) * geometry.hip_offset_m
    y = d * c0 + h * s0
    z = d * s0 - h * c0
    dx = np.stack(np.broadcast_arrays(0.0 * q0, -h, -l2 * np.cos(q1 + q2)), axis=-1)  # d x / d q
    dh = np.stack(np.broadcast_arrays(0.0 * q0, x, -l2 * np.sin(q1 + q2)), axis=-1)   # d h / d q
    dy = dh * s0[..., None]
    dz = -dh * c0[..., None]
    dy[..., 0] = -z
    dz[..., 0] = y
    return np.stack([dx, dy, dz], axis=-2)


def leg_ik(foot_m: np.ndarray, side: np.ndarray, geometry: LegGeometry = LegGeometry()) -> np.ndarray:
    """Joint angles that put the foot centre at ``foot_m`` (analytic inverse of :func:`leg_fk`).

    The knee is always bent backward (calf angle in [-pi, 0]) and the foot is taken to be below the hip
    in the leg plane (``thigh_length cos(thigh) + calf_length cos(thigh + calf) >= 0``), which covers
    walking; the joint ranges of the model also allow poses outside that, which this does not invert.
    Targets out of reach are pulled onto the workspace boundary (fully stretched or fully folded leg)
    rather than raising.

    Args:
        foot_m: (..., 3) m, foot centre relative to the hip joint, trunk-aligned axes.
        side: (...,) +1 for a left leg, -1 for a right leg.
        geometry: the leg's link lengths.

    Returns:
        (..., 3) rad, (hip, thigh, calf) joint angles.
    """
    foot_m = np.asarray(foot_m, dtype=float)
    if foot_m.shape[-1:] != (3,):
        raise ValueError(f"foot_m must have shape (..., 3), got {foot_m.shape}")
    x, y, z = foot_m[..., 0], foot_m[..., 1], foot_m[..., 2]
    l1, l2 = geometry.thigh_length_m, geometry.calf_length_m
    d = np.asarray(side, dtype=float) * geometry.hip_offset_m
    # Abduction: (y, z) = R_x(q0) (d, -h) with h >= 0 the downward extent in the leg plane.
    h = np.sqrt(np.maximum(y * y + z * z - d * d, 0.0))
    q0 = np.arctan2(z, y) - np.arctan2(-h, d)
    q0 = (q0 + np.pi) % (2.0 * np.pi) - np.pi
    # Sagittal two-link problem in the leg plane: foot at (x, -h) from the thigh joint.
    r2 = x * x + h * h
    cos_knee = np.clip((r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2), -1.0, 1.0)
    q2 = -np.arccos(cos_knee)
    q1 = np.arctan2(-x, h) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    return np.stack(np.broadcast_arrays(q0, q1, q2), axis=-1)


@dataclasses.dataclass(frozen=True)
class TrotGait:
    """A trot: diagonal leg pairs (FL+RR, FR+RL) alternate, each foot tracing a fixed loop in its hip
    frame. In stance the foot moves backward at constant speed over ``stride_m``; in swing it returns
    with zero velocity at lift-off and touch-down and rises ``step_height_m`` at mid-swing.

    The nominal forward speed is ``stride_m * frequency_hz / duty_factor`` (feet that do not slip);
    ``stride_m = 0`` marches in place, and :meth:`stand` is the still standing pose.

    Attributes:
        frequency_hz: gait cycles per second, Hz (> 0).
        stride_m: foot travel relative to the hip during one stance, m (>= 0 forward, < 0 backward).
        step_height_m: foot lift at mid-swing, m (>= 0).
        duty_factor: fraction of the cycle each foot is in stance, in (0, 1); 0.5 is a pure trot.
        hip_height_m: vertical distance from the hip joints down to the foot centres in stance, m. The
            model's hips are at the trunk centre height, so the trunk stands at about
            ``hip_height_m + geometry.foot_radius_m`` (0.30 m by default, the ``home`` keyframe).
        foot_x_offset_m: forward shift of the foot loop's centre from under the hip, m.
        stance_width_m: extra lateral foot placement outboard of the thigh plane, m.
        ramp_time_s: the stride and step height grow linearly from 0 over this time from t = 0, s
            (0 disables the ramp), so a robot standing still starts smoothly.
        load_n: weight the stance feet carry, N (the robot's mass times |g|); 0 disables the load
            compensation. Position servos yield under load (``tau = kp * (target - q)``); with a
            compliant knee-backward leg that yield is a backward step of the trunk at every
            touchdown, a drift of ~0.1 m/s when marching in place. Stance-leg targets are therefore
            offset by ``-J^T f / kp`` with ``f = (0, 0, load_n / n_stance)``, the share of the weight
            on each stance foot (``J`` from :func:`leg_jacobian`).
        servo_kp_nm_per_rad: the position servos' stiffness used by the load compensation and the
            velocity lead, N m/rad.
        servo_kd_nm_s_per_rad: the velocity-proportional resistance each joint meets (the servo's
            ``kv`` plus the joint's damping), N m s/rad; 0 disables the velocity lead. A position servo
            with damping lags a moving target by ``kd / kp * dq/dt`` (a late, short swing: the feet
            land behind their targets and the trot loses ~20% of its speed), so the targets lead by
            that much: ``q_target = q_ik + kd / kp * dq_ik/dt``.
        geometry: the leg's link lengths (:meth:`LegGeometry.from_model` reads them from a model).

    :meth:`from_model` fills ``geometry``, ``load_n`` and ``servo_kp_nm_per_rad`` from a compiled model.
    """

    frequency_hz: float = 2.5
    stride_m: float = 0.10
    step_height_m: float = 0.06
    duty_factor: float = 0.5
    hip_height_m: float = 0.28
    foot_x_offset_m: float = 0.0
    stance_width_m: float = 0.0
    ramp_time_s: float = 0.5
    load_n: float = 0.0
    servo_kp_nm_per_rad: float = 80.0
    servo_kd_nm_s_per_rad: float = 0.0
    geometry: LegGeometry = dataclasses.field(default_factory=LegGeometry)

    @classmethod
    def from_model(cls, model, **kwargs) -> "TrotGait":
        """A gait for a compiled MjModel of the bundled quadruped: leg geometry, weight (total mass
        times |gravity|), servo stiffness (the actuators' ``kp``) and resistance (``kv`` plus joint
        damping) are read from the model, where all 12 servos must be alike; ``kwargs`` set the other
        fields (and may override these)."""
        kp = np.asarray(model.actuator_gainprm[:, 0], dtype=float)
        kd = -np.asarray(model.actuator_biasprm[:, 2], dtype=float)
        kd = kd + model.dof_damping[model.jnt_dofadr[model.actuator_trnid[:, 0]]]
        if model.nu != 12 or not (np.allclose(kp, kp[0]) and np.allclose(kd, kd[0])):
            raise ValueError(f"expected 12 alike position actuators, got nu={model.nu}, kp={kp.tolist()}, "
                             f"kv + joint damping={kd.tolist()}")
        defaults = dict(geometry=LegGeometry.from_model(model),
                        load_n=float(np.sum(model.body_mass) * np.linalg.norm(model.opt.gravity)),
                        servo_kp_nm_per_rad=float(kp[0]), servo_kd_nm_s_per_rad=float(kd[0]))
        return cls(**{**defaults, **kwargs})

    def __post_init__(self) -> None:
        def check(name, ok, expected):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and ok(value)):
                raise ValueError(f"{name} must be {expected}, got {value!r}")

        check("frequency_hz", lambda v: v > 0, "a finite frequency > 0 Hz")
        check("stride_m", lambda v: True, "a finite length in m")
        check("step_height_m", lambda v: v >= 0, "a finite height >= 0 m")
        check("duty_factor", lambda v: 0 < v < 1, "a fraction in (0, 1)")
        check("hip_height_m", lambda v: v > 0, "a finite height > 0 m")
        check("foot_x_offset_m", lambda v: True, "a finite length in m")
        check("stance_width_m", lambda v: True, "a finite length in m")
        check("ramp_time_s", lambda v: v >= 0, "a finite time >= 0 s")
        check("load_n", lambda v: v >= 0, "a finite weight >= 0 N")
        check("servo_kp_nm_per_rad", lambda v: v > 0, "a finite stiffness > 0 N m/rad")
        check("servo_kd_nm_s_per_rad", lambda v: v >= 0, "a finite damping >= 0 N m s/rad")
        if not isinstance(self.geometry, LegGeometry):
            raise ValueError(f"geometry must be a LegGeometry, got {type(self.geometry).__name__}")
        g = self.geometry
        reach = g.thigh_length_m + g.calf_length_m
        far = math.hypot(abs(self.stride_m) / 2 + abs(self.foot_x_offset_m), self.hip_height_m)
        if far >= reach:
            raise ValueError(
                f"the foot loop is out of reach: its farthest point is {far:.3f} m from the hip in the "
                f"leg plane, the stretched leg is {reach:.3f} m. Lower hip_height_m "
                f"({self.hip_height_m}) or stride_m ({self.stride_m}).")
        near = self.hip_height_m - self.step_height_m
        if near <= abs(g.thigh_length_m - g.calf_length_m) or near <= 0:
            raise ValueError(f"step_height_m ({self.step_height_m}) must leave the swing foot below the "
                             f"hip: hip_height_m - step_height_m = {near:.3f} m")

    @property
    def nominal_speed_mps(self) -> float:
        """Forward trunk speed if stance feet do not slip, m/s."""
        return self.stride_m * self.frequency_hz / self.duty_factor

    def _feet_and_stance(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        t = float(t)
        ramp = 1.0 if self.ramp_time_s == 0 else min(max(t / self.ramp_time_s, 0.0), 1.0)
        stride, height = ramp * self.stride_m, ramp * self.step_height_m
        phase = (t * self.frequency_hz + TROT_PHASE) % 1.0                      # (4,)
        stance = phase < self.duty_factor
        s_stance = phase / self.duty_factor                                     # 0..1 in stance
        s_swing = (phase - self.duty_factor) / (1.0 - self.duty_factor)         # 0..1 in swing
        x_stance = stride * (0.5 - s_stance)
        x_swing = stride * (s_swing - np.sin(2 * np.pi * s_swing) / (2 * np.pi) - 0.5)
        z_swing = height * 0.5 * (1.0 - np.cos(2 * np.pi * s_swing))
        x = np.where(stance, x_stance, x_swing) + self.foot_x_offset_m
        z = np.where(stance, 0.0, z_swing) - self.hip_height_m
        y = SIDE * (self.geometry.hip_offset_m + self.stance_width_m)
        return np.stack([x, y, z], axis=-1), stance

    def feet(self, t: float) -> np.ndarray:
        """Foot-centre targets at time ``t`` (s), (4, 3) m in each leg's hip frame, :data:`LEGS` order."""
        return self._feet_and_stance(t)[0]

    def stance(self, t: float) -> np.ndarray:
        """Which feet are in stance at time ``t`` (s): (4,) bool, :data:`LEGS` order."""
        return self._feet_and_stance(t)[1]

    def targets(self, t: float) -> np.ndarray:
        """Joint targets at time ``t`` (s): (12,) rad in actuator order (:data:`ACTUATOR_NAMES`)."""
        feet, stance = self._feet_and_stance(t)
        q = leg_ik(feet, SIDE, self.geometry)                                   # (4, 3)
        if self.servo_kd_nm_s_per_rad > 0:
            h = _LEAD_DT_S
            dq_dt = (leg_ik(self.feet(t + h), SIDE, self.geometry)
                     - leg_ik(self.feet(t - h), SIDE, self.geometry)) / (2.0 * h)
            q = q + (self.servo_kd_nm_s_per_rad / self.servo_kp_nm_per_rad) * dq_dt
        if self.load_n > 0 and stance.any():
            f_z = np.where(stance, self.load_n / np.count_nonzero(stance), 0.0)    # (4,) N on each foot
            jac = leg_jacobian(q, SIDE, self.geometry)                          # (4, 3, 3)
            q = q - jac[:, 2, :] * (f_z / self.servo_kp_nm_per_rad)[:, None]
        return q.reshape(12)

    def stand(self) -> np.ndarray:
        """The standing pose with all feet at the loop centre (load-compensated like :meth:`targets`):
        (12,) rad in actuator order."""
        return dataclasses.replace(self, stride_m=0.0, step_height_m=0.0).targets(0.0)
