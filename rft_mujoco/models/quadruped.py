"""Constants of the bundled quadruped (``quadruped.xml``): leg, actuator and foot names in model order."""

from __future__ import annotations

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
