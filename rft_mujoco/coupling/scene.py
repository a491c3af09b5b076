"""Sand declared in the MJCF itself, through ``<custom>`` fields, attached with one call.

A scene file says which bodies touch which sand::

    <custom>
      <text    name="rft/media"          data="li_loose_glass_beads"/>  <!-- a preset name, or: -->
      <numeric name="rft/media"          data="1450 0.4 0.4"/>          <!-- rho_c kg/m^3, mu_int, mu_surf -->
      <text    name="rft/bodies"         data="FL_foot FR_foot RL_foot RR_foot"/>  <!-- default: all -->
      <numeric name="rft/surface_height" data="0"/>                     <!-- m (flat surface) -->
      <text    name="rft/heightfield"    data="terrain"/>               <!-- hfield geom as the surface -->
      <numeric name="rft/region"         data="-1 1 -0.5 0.5"/>         <!-- xmin xmax ymin ymax, m -->
      <numeric name="rft/deformable"     data="2 1 0.01 0.5 0"/>        <!-- Lx Ly cell [cx cy], m: footprints -->
      <numeric name="rft/resolution"     data="0.01"/>                  <!-- m, or text preset name -->
      <text    name="rft/replaces"       data="floor"/>                 <!-- rigid geoms the sand replaces -->
    </custom>

Several sands: put a name between ``rft`` and the key (``rft/beach/media``, ``rft/beach/bodies``, ...);
each named group is one :class:`~rft_mujoco.SandHandle`. The geoms listed in ``replaces`` stop
colliding while the sand is attached (their ``contype``/``conaffinity`` are set to 0 on the MjModel and
restored at detach): that is how a rigid floor becomes a sand bed. ``deformable`` makes the flat surface a
:class:`~rft_mujoco.DeformableSurface` of that size, cell and centre (default centre 0 0; not with a
heightfield or a region).
"""

from __future__ import annotations

import mujoco
import numpy as np

from rft_mujoco.coupling.handle import SandHandle, attach
from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.physics.media import Media, get_media
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion

PREFIX = "rft/"
KEYS = ("media", "bodies", "surface_height", "heightfield", "region", "resolution", "replaces", "deformable")


def _custom_fields(model) -> dict[str, dict[str, object]]:
    groups: dict[str, dict[str, object]] = {}
    raw = bytes(model.text_data)
    items = [(model.numeric(i).name, np.array(model.numeric(i).data, dtype=float)) for i in range(model.nnumeric)]
    for i in range(model.ntext):
        adr, size = int(model.text_adr[i]), int(model.text_size[i])
        items.append((mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TEXT, i) or "",
                      raw[adr:adr + size].rstrip(b"\0").decode().strip()))
    for name, value in items:
        if not name.startswith(PREFIX):
            continue
        parts = name[len(PREFIX):].split("/")
        group, key = ("default", parts[0]) if len(parts) == 1 else (parts[0], parts[1])
        if key not in KEYS or len(parts) > 2:
            raise ValueError(f"unknown sand field {name!r} in <custom>; valid keys: "
                             f"{[PREFIX + k for k in KEYS]} (optionally rft/<group>/<key>)")
        groups.setdefault(group, {})[key] = value
    return groups


def _media(value, where: str) -> Media:
    if isinstance(value, str):
        return get_media(value)
    if value.size not in (2, 3):
        raise ValueError(f"{where}: numeric media must be 'rho_c mu_int [mu_surf]', got {value.tolist()}")
    return Media(float(value[0]), float(value[1]), float(value[2]) if value.size == 3 else None)


def _one_number(value, where: str, unit: str) -> float:
    """The single number of a ``<numeric>`` field (ValueError naming the field for any other count)."""
    if isinstance(value, str):
        raise ValueError(f"{where} must be a <numeric> with one number in {unit}, got the text {value!r}")
    values = np.atleast_1d(value)
    if values.size != 1:
        raise ValueError(f"{where} must hold one number in {unit}, got {values.tolist()}")
    return float(values[0])


def attach_scene(model, **kwargs) -> list[SandHandle]:
    """Attach every sand declared in the model's ``<custom>`` fields; returns one handle per sand.

    Keyword arguments are passed to :func:`rft_mujoco.attach` (e.g. ``stabilize``, ``guards``).
    Raises ValueError if the model declares no sand.
    """
    groups = _custom_fields(model)
    if not groups:
        raise ValueError("the model declares no sand: add <custom><text name=\"rft/media\" "
                         "data=\"li_loose_glass_beads\"/></custom> (see rft_mujoco.coupling.scene)")
    handles = []
    try:
        for name, f in groups.items():
            where = f"sand {name!r}"
            if "media" not in f:
                raise ValueError(f"{where} has no rft/media field; give a preset name or 'rho_c mu_int mu_surf'")
            media = _media(f["media"], where)
            bodies = f["bodies"].split() if "bodies" in f else None
            if "heightfield" in f:
                surf = HeightfieldSurface.from_model(model, f["heightfield"])
            else:
                surf = FlatSurface(_one_number(f.get("surface_height", 0.0), f"{where}: rft/surface_height", "m"))
            if "deformable" in f:
                d = np.atleast_1d(f["deformable"])
                if isinstance(f["deformable"], str) or d.size not in (3, 5) or "heightfield" in f or "region" in f:
                    raise ValueError(f"{where}: rft/deformable must be a <numeric> 'Lx Ly cell' or 'Lx Ly cell cx "
                                     "cy' in m over a flat surface (no rft/heightfield or rft/region), got "
                                     f"{f['deformable']!r}")
                surf = DeformableSurface(surf.height, (d[0], d[1]), float(d[2]),
                                         (d[3], d[4]) if d.size == 5 else (0.0, 0.0))
            if "region" in f:
                r = np.atleast_1d(f["region"])
                if r.size != 4:
                    raise ValueError(f"{where}: rft/region must be 'xmin xmax ymin ymax', got {r.tolist()}")
                surf = SandRegion(surf, (r[0], r[1]), (r[2], r[3]))
            res = f.get("resolution", "default")
            res = res if isinstance(res, str) else _one_number(res, f"{where}: rft/resolution", "m")
            handle = attach(model, media, bodies, surf, res, **kwargs)
            if "replaces" in f:
                handle.replace_rigid(f["replaces"].split())
            handles.append(handle)
    except Exception:
        for h in handles:
            h.detach()
        raise
    return handles
