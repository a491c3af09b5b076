"""rft_mujoco: 3D Resistive Force Theory (Agarwal, Goldman & Kamrin, PNAS 2023) sand forces for MuJoCo.

Quick start::

    import mujoco, rft_mujoco
    model = mujoco.MjModel.from_xml_path("scene.xml")
    sand = rft_mujoco.attach(model, rft_mujoco.MALADEN_GLASS_BEADS, bodies=["foot"], surface_height=0.0)
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data)          # includes the sand forces
    sand.diagnostics(data).force         # per-body sand force, N
    sand.detach()
"""

from rft_mujoco.physics.law import PUBLISHED, Guards, stress_per_depth
from rft_mujoco.physics.media import (DEM_GLASS_BEADS, LI_LOOSE_GLASS_BEADS, MALADEN_GLASS_BEADS, MPM_VALIDATION, PRESETS,
                    Media, get_media)
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion
from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.coupling.handle import Diagnostics, SandHandle, SolveCounters, attach, attached_handles, detach_all
from rft_mujoco.coupling.monitor import RFTValidityWarning, ValidityMonitor
from rft_mujoco.coupling.scene import attach_scene
from rft_mujoco.coupling.checks import SandSetupWarning
from rft_mujoco.forces import element_forces

__all__ = [
    "Media", "PRESETS", "get_media", "MPM_VALIDATION", "DEM_GLASS_BEADS", "LI_LOOSE_GLASS_BEADS",
    "MALADEN_GLASS_BEADS", "element_forces", "stress_per_depth", "Guards", "PUBLISHED",
    "FlatSurface", "HeightfieldSurface", "SandRegion", "DeformableSurface", "attach", "attach_scene", "attached_handles", "detach_all", "SandHandle", "Diagnostics", "SolveCounters",
    "RFTValidityWarning", "ValidityMonitor", "SandSetupWarning",
]
__version__ = "0.1.0"
