"""Batched sand on MuJoCo Warp (optional extra ``pip install 'rft_mujoco[warp]'``): thousands of worlds per step.

Quick start::

    import mujoco, mujoco_warp as mjw, rft_mujoco.warp as rw
    mj_model = mujoco.MjModel.from_xml_path("scene.xml")
    m = mjw.put_model(mj_model)
    d = mjw.put_data(mj_model, mujoco.MjData(mj_model), nworld=4096)
    sand = rw.attach(mj_model, m, "li_loose_glass_beads", bodies=["foot"], surface_height=0.0, data=d)
    mjw.step(m, d)                      # every world includes the sand
    sand.forces(d)                      # (nworld, B, 3) N
    # attach(..., solve="implicit"): the CPU path's implicit solve in every world (docs/warp.md)

The core library (``rft_mujoco``) never imports this package.
"""

try:
    import mujoco_warp as _mjw  # noqa: F401
    import warp as _wp  # noqa: F401
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(f"rft_mujoco.warp needs MuJoCo Warp ({exc}); install the optional extra: "
                      "pip install 'rft_mujoco[warp]' (or pip install mujoco-warp)") from exc

from rft_mujoco.warp.handle import WarpDiagnostics, WarpSandHandle, attach

__all__ = ["attach", "WarpSandHandle", "WarpDiagnostics"]
