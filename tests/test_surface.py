"""Surface elements: convergence to analytic areas/volumes, meshes from inline MJCF, frames, errors."""

import math
import os
import warnings

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import special

from rft_mujoco.geometry import occlusion
from rft_mujoco.geometry import meshes, surface
from rft_mujoco.models import __file__ as _models_init
from rft_mujoco.geometry.surface import Elements

MODELS = os.path.dirname(_models_init)

SIZES = [surface.RESOLUTIONS[k] for k in ("coarse", "default", "fine", "reference")]
FINE_TOL = 0.01        # relative area/volume error allowed at the "fine" preset
ROUNDOFF = 1e-9        # relative error treated as exact (errors below this need not decrease)


def ellipsoid_area(a, b, c):
    """Exact ellipsoid area (Legendre's form with incomplete elliptic integrals)."""
    a, b, c = sorted((a, b, c), reverse=True)
    if math.isclose(a, c):
        return 4 * math.pi * a * a
    phi = math.acos(c / a)
    m = a * a * (b * b - c * c) / (b * b * (a * a - c * c))
    return 2 * math.pi * c * c + 2 * math.pi * a * b / math.sin(phi) * (
        special.ellipeinc(phi, m) * math.sin(phi) ** 2 + special.ellipkinc(phi, m) * math.cos(phi) ** 2)


def test_ellipsoid_reference_area_matches_quadrature():
    from scipy import integrate
    a, b, c = 0.05, 0.03, 0.02
    f = lambda t, p: math.sin(t) * math.sqrt((b * c * math.sin(t) * math.cos(p)) ** 2
                                             + (a * c * math.sin(t) * math.sin(p)) ** 2
                                             + (a * b * math.cos(t)) ** 2)
    quad, _ = integrate.dblquad(f, 0, 2 * math.pi, 0, math.pi, epsabs=1e-14, epsrel=1e-10)
    assert ellipsoid_area(a, b, c) == pytest.approx(quad, rel=1e-8)


R, HL, ABC, HE = 0.05, 0.04, (0.05, 0.03, 0.02), (0.04, 0.03, 0.02)
PRIMITIVES = {
    # name: (builder(size), exact area, exact volume)
    "sphere": (lambda h: surface.sphere(R, h), 4 * math.pi * R**2, 4 / 3 * math.pi * R**3),
    "ellipsoid": (lambda h: surface.ellipsoid(ABC, h), ellipsoid_area(*ABC), 4 / 3 * math.pi * np.prod(ABC)),
    "box": (lambda h: surface.box(HE, h), 8 * (HE[0] * HE[1] + HE[1] * HE[2] + HE[0] * HE[2]), 8 * np.prod(HE)),
    "cylinder": (lambda h: surface.cylinder(0.03, HL, h), 2 * math.pi * 0.03 * (0.03 + 2 * HL),
                 math.pi * 0.03**2 * 2 * HL),
    "capsule": (lambda h: surface.capsule(0.02, HL, h), 2 * math.pi * 0.02 * 2 * HL + 4 * math.pi * 0.02**2,
                math.pi * 0.02**2 * 2 * HL + 4 / 3 * math.pi * 0.02**3),
    # A tiny foot: 1 cm sphere at the 1 cm preset keeps the minimum tessellation.
    "tiny_sphere": (lambda h: surface.sphere(0.005, h), 4 * math.pi * 0.005**2, 4 / 3 * math.pi * 0.005**3),
}


@pytest.mark.parametrize("name", PRIMITIVES)
def test_primitive_converges_with_outward_unit_normals(name):
    build, area, volume = PRIMITIVES[name]
    prev = None
    for h in SIZES:
        el = build(h)
        err = (abs(el.area() / area - 1), abs(el.enclosed_volume() / volume - 1))
        if prev is not None:
            for e, p in zip(err, prev):
                # (equal up to round-off where the minimum tessellation sets both meshes)
                assert e <= max(p * (1 + 1e-9), ROUNDOFF), (name, h, err, prev)
        if h <= surface.RESOLUTIONS["fine"]:
            assert max(err) < FINE_TOL, (name, h, err)
        prev = err
        # Convex and centred at the origin: every element faces away from the centre.
        assert np.all(np.einsum("ij,ij->i", el.centroids, el.normals) >= 0)
        assert np.allclose(np.linalg.norm(el.normals, axis=1), 1)
        assert np.all(el.areas > 0)
        # Closed surface: sum n dA = 0.
        assert np.allclose(el.normals.T @ el.areas, 0, atol=1e-9 * area)


def test_minimum_tessellation_for_tiny_geoms():
    el = surface.sphere(0.005, 0.01)
    assert len(el) >= surface.MIN_CIRCLE_SEGMENTS * surface.MIN_CIRCLE_SEGMENTS // 2
    # >= 12 longitudes in the equatorial band
    equator = np.abs(el.normals[:, 2]) < 0.3
    assert np.count_nonzero(equator) >= surface.MIN_CIRCLE_SEGMENTS
    b = surface.box([0.001, 0.001, 0.001], 0.01)
    assert len(b) == 6 * surface.MIN_EDGE_CELLS**2
    c = surface.cylinder(0.002, 0.001, 0.01)
    side = np.abs(c.normals[:, 2]) < 0.5
    assert np.count_nonzero(side) >= surface.MIN_CIRCLE_SEGMENTS * surface.MIN_EDGE_CELLS


def test_sphere_centroids_on_surface_and_normals_radial():
    el = surface.sphere(0.05, 0.01)
    assert np.allclose(np.linalg.norm(el.centroids, axis=1), 0.05)
    assert np.allclose(el.centroids / 0.05, el.normals)


def test_ellipsoid_with_equal_radii_is_the_sphere():
    e = surface.ellipsoid([0.05, 0.05, 0.05], 0.01)
    s = surface.sphere(0.05, 0.01)
    assert len(e) == len(s)
    assert np.allclose(e.centroids, s.centroids, atol=1e-12)
    assert np.allclose(e.normals, s.normals, atol=1e-12)
    assert np.allclose(e.areas, s.areas, rtol=1e-9)


def test_ellipsoid_centroids_on_surface_with_true_normals():
    abc = np.array(ABC)
    el = surface.ellipsoid(abc, 0.01)
    assert np.allclose(((el.centroids / abc) ** 2).sum(1), 1)
    grad = el.centroids / abc**2
    assert np.allclose(grad / np.linalg.norm(grad, axis=1, keepdims=True), el.normals)


def test_element_size_bounded_by_target():
    h = 0.005
    for el in (surface.sphere(0.1, h), surface.box([0.1, 0.05, 0.02], h), surface.cylinder(0.05, 0.1, h)):
        # a flat-ish cell of edge <= h (plus slack for curvature/triangular polar cells) has area <= h^2
        assert el.areas.max() <= 1.1 * h * h


def test_mirror_symmetry():
    """Quarter-turn symmetric grids give zero net force for symmetric loads: check sum c A = 0."""
    for el in (surface.sphere(0.05, 0.01), surface.capsule(0.02, 0.03, 0.01), surface.cylinder(0.03, 0.02, 0.007)):
        assert np.allclose(el.centroids.T @ el.areas, 0, atol=1e-15)


# --- Elements ------------------------------------------------------------------------------------------
def test_transformed_matches_loop():
    el = surface.box([0.01, 0.02, 0.03], 0.01)
    q = np.array([0.9, 0.1, -0.3, 0.2])
    q /= np.linalg.norm(q)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, q)
    mat = mat.reshape(3, 3)
    pos = np.array([0.1, -0.2, 0.3])
    out = el.transformed(pos, mat)
    for i in range(len(el)):
        assert np.allclose(out.centroids[i], pos + mat @ el.centroids[i])
        assert np.allclose(out.normals[i], mat @ el.normals[i])
    assert np.array_equal(out.areas, el.areas)
    assert out.enclosed_volume() == pytest.approx(el.enclosed_volume(), rel=1e-9)
    assert np.allclose(surface._quat_to_mat(q), mat)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
       st.lists(st.floats(-1, 1), min_size=3, max_size=3))
def test_rigid_motion_keeps_area_and_volume(q, pos):
    el = surface.capsule(0.02, 0.03, 0.01)
    out = el.transformed(pos, surface._quat_to_mat(q))
    assert out.area() == pytest.approx(el.area(), rel=1e-12)
    assert out.enclosed_volume() == pytest.approx(el.enclosed_volume(), rel=1e-9)
    assert np.allclose(np.linalg.norm(out.normals, axis=1), 1)


def test_transformed_rejects_bad_arguments():
    el = surface.sphere(0.01, 0.01)
    with pytest.raises(ValueError, match=r"pos must be .*\(3,\).*got shape \(2,\)"):
        el.transformed([0, 0], np.eye(3))
    with pytest.raises(ValueError, match=r"got shape \(2, 3\)"):
        el.transformed([0, 0, 0], np.zeros((2, 3)))
    with pytest.raises(ValueError, match="rotation"):
        el.transformed([0, 0, 0], 2 * np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        el.transformed([0, 0, 0], -np.eye(3))


def test_concatenate_and_empty():
    empty = Elements.concatenate([])
    assert len(empty) == 0 and empty.centroids.shape == (0, 3) and empty.areas.shape == (0,)
    assert empty.area() == 0 and empty.enclosed_volume() == 0
    a, b = surface.sphere(0.01, 0.01), surface.box([0.01] * 3, 0.01)
    both = Elements.concatenate([a, empty, b])
    assert len(both) == len(a) + len(b)
    assert both.area() == pytest.approx(a.area() + b.area())


def test_elements_validate_and_are_read_only():
    with pytest.raises(ValueError, match=r"\(n, 3\).*got shape \(4, 2\)"):
        Elements(np.zeros((4, 2)), np.zeros((4, 3)), np.ones(4))
    with pytest.raises(ValueError, match="agree in N"):
        Elements(np.zeros((4, 3)), np.tile([0, 0, 1.0], (4, 1)), np.ones(3))
    with pytest.raises(ValueError, match="> 0"):
        Elements(np.zeros((1, 3)), [[0, 0, 1.0]], [0.0])
    with pytest.raises(ValueError, match="unit"):
        Elements(np.zeros((1, 3)), [[0, 0, 2.0]], [1.0])
    el = surface.sphere(0.01, 0.01)
    with pytest.raises(ValueError):
        el.areas[0] = 1.0
    for bad in ((-1, 0.01), (0.01, 0.0), (0.01, float("nan"))):
        with pytest.raises(ValueError, match="positive finite length"):
            surface.sphere(*bad)
    with pytest.raises(ValueError, match=r"radii must be a \(3,\).*got shape \(2,\)"):
        surface.ellipsoid([0.1, 0.2], 0.01)


# --- resolution ------------------------------------------------------------------------------------------
def test_element_size():
    assert surface.element_size("default") == surface.RESOLUTIONS["default"]
    assert surface.element_size(0.003) == 0.003
    assert surface.element_size(np.float32(0.25)) == 0.25
    with pytest.raises(ValueError, match=r"unknown resolution 'medium'.*coarse.*default.*fine.*reference"):
        surface.element_size("medium")
    for bad in (0, -0.01, float("inf"), float("nan"), True, None, [0.01]):
        with pytest.raises(ValueError, match="resolution"):
            surface.element_size(bad)
    with pytest.raises(TypeError):
        surface.RESOLUTIONS["coarse"] = 1.0   # presets are read-only


# --- meshes ----------------------------------------------------------------------------------------------
CUBE_V = "-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1"
CUBE_F = "0 2 1 0 3 2 4 5 6 4 6 7 0 1 5 0 5 4 1 2 6 1 6 5 2 3 7 2 7 6 3 0 4 3 4 7"


def mesh_model(faces=CUBE_F, scale="0.01 0.02 0.03", geom_extra=""):
    xml = f"""
    <mujoco>
      <asset><mesh name="cube" vertex="{CUBE_V}" face="{faces}" scale="{scale}"/></asset>
      <worldbody>
        <body name="b" pos="0 0 1">
          <freejoint/>
          <geom name="m" type="mesh" mesh="cube" pos="0.1 0 0" {geom_extra}/>
          <geom name="s" type="sphere" size="0.02" pos="0 0.2 0" mass="1"/>
        </body>
      </worldbody>
    </mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def test_mesh_from_mjcf():
    model = mesh_model()
    g = model.geom("m").id
    assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
    exact_area = 8 * (0.01 * 0.02 + 0.02 * 0.03 + 0.01 * 0.03)
    exact_volume = 8 * 0.01 * 0.02 * 0.03
    coarse = surface.geom_elements(model, g, 1.0)          # one grid cell: one element per face
    assert len(coarse) == 6
    for h in (0.01, 0.005):
        el = surface.geom_elements(model, g, h)
        assert el.area() == pytest.approx(exact_area, rel=1e-6)
        assert el.enclosed_volume() == pytest.approx(exact_volume, rel=1e-6)
        assert np.all(np.einsum("ij,ij->i", el.centroids, el.normals) > 0)
        # every element is a cluster of pieces (<= PIECE_FRACTION h) whose centroids share a grid cell
        assert el.areas.max() <= ((meshes.VOXEL_SCALE + meshes.PIECE_FRACTION) * h) ** 2 * (1 + 1e-6)
        # normals are the six axis directions
        assert np.allclose(np.abs(el.normals).max(1), 1)


def test_mesh_pieces_match_plain_integration():
    v = np.array([[0, 0, 0], [0.3, 0, 0], [0.29, 0.01, 0.0]])      # a sliver 0.3 m long, 1 cm wide
    # A lone triangle is an open mesh: it warns, and still gives elements.
    with pytest.warns(UserWarning, match="'tri' is used as given.*open"):
        el = surface.mesh(v, [[0, 1, 2]], size=0.01, name="tri")
    assert el.area() == pytest.approx(0.5 * 0.3 * 0.01) and np.allclose(el.normals, [0, 0, 1])
    # one element per grid cell the sliver crosses (a line of length L crosses at most sqrt(3) L / cell
    # cells of the turned grid), not k^2 = 900 sub-triangles as by longest-edge cutting
    assert len(el) <= math.ceil(math.sqrt(3) * 0.3 / (meshes.VOXEL_SCALE * 0.01)) + 2
    c, a, tri = meshes._pieces(v[None], np.array([0.5 * 0.3 * 0.01]), 0.005)
    assert a.sum() == pytest.approx(0.0015) and np.allclose((c * a[:, None]).sum(0) / a.sum(), v.mean(0))
    # each piece against plain sampling: uniform points of the triangle binned by the (s, w) grid of the
    # pieces (x = T + s ((P - T) + w (Q - P)), T = v0 opposite the shortest edge, 60 x 3 cells)
    rng = np.random.default_rng(0)
    u = rng.random((1_000_000, 2))
    u[u.sum(1) > 1] = 1 - u[u.sum(1) > 1]
    pts = v[0] + u[:, :1] * (v[1] - v[0]) + u[:, 1:] * (v[2] - v[0])
    ab = np.linalg.lstsq(np.column_stack([v[1] - v[0], v[2] - v[1]])[:2], (pts - v[0])[:, :2].T, rcond=None)[0]
    cell = np.minimum(np.floor(ab[0] * 60), 59).astype(int) * 3 + np.minimum(np.floor(ab[1] / ab[0] * 3), 2).astype(int)
    assert len(a) == 180
    sampled_area = np.bincount(cell, minlength=180) / len(pts) * 0.0015
    assert np.allclose(sampled_area, a, rtol=0.2, atol=2e-7)
    big = a > 5e-6                                            # pieces with enough samples for their centroid
    sampled_c = np.stack([np.bincount(cell, pts[:, d], minlength=180) for d in range(3)], 1) \
        / np.maximum(np.bincount(cell, minlength=180), 1)[:, None]
    assert np.abs(sampled_c[big] - c[big]).max() <= 2e-4


def test_mesh_drops_degenerate_faces():
    v = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1],
                  [-1, 1, 1], [0, -1, -1.0]]) * 0.01
    f = np.array(CUBE_F.split(), dtype=int).reshape(-1, 3)
    el0 = surface.mesh(v, f)
    el1 = surface.mesh(v, np.vstack([f, [[0, 8, 1]]]))    # collinear: zero area
    assert len(el1) == len(el0) == 12


def test_inverted_mesh_is_turned_outside_in():
    flipped = " ".join(" ".join(t[::-1]) for t in np.array(CUBE_F.split()).reshape(-1, 3))
    model = mesh_model(faces=flipped)
    with pytest.warns(UserWarning, match=r"mesh 'cube' is used as given.*inside out"):
        el = surface.geom_elements(model, model.geom("m").id, 0.01)
    assert el.enclosed_volume() == pytest.approx(8 * 0.01 * 0.02 * 0.03, rel=1e-6)


def test_inconsistent_winding_is_repaired():
    f = np.array(CUBE_F.split(), dtype=int).reshape(-1, 3)
    f[0] = f[0, ::-1]
    with pytest.warns(UserWarning, match="1 faces were wound against their neighbours"):
        el = surface.mesh(np.array(CUBE_V.split(), dtype=float).reshape(-1, 3), f, name="half")
    assert el.enclosed_volume() == pytest.approx(8.0)


def test_open_mesh_warns_once():
    open_faces = " ".join(CUBE_F.split()[:-6])   # drop the two -x faces
    model = mesh_model(faces=open_faces)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        el = surface.geom_elements(model, model.geom("m").id, 0.01)
    msgs = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    assert len(msgs) == 1 and "'cube'" in msgs[0] and "open" in msgs[0]
    assert len(el) > 0


def test_mesh_rejects_bad_arrays():
    v = np.zeros((3, 3))
    with pytest.raises(ValueError, match=r"got shape \(3, 2\)"):
        surface.mesh(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(ValueError, match=r"faces of mesh 'mesh'.*got shape \(3,\)"):
        surface.mesh(v, [0, 1, 2])
    with pytest.raises(ValueError, match="index vertices 0..2"):
        surface.mesh(v + np.eye(3), [[0, 1, 3]])


# --- geoms and bodies ------------------------------------------------------------------------------------
PRIMS_XML = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="b" pos="0.3 0.1 0.5" euler="10 20 30">
      <freejoint/>
      <geom name="sph" type="sphere" size="0.02" pos="0.1 -0.05 0.02"/>
      <geom name="ell" type="ellipsoid" size="0.03 0.02 0.01" pos="0 0 -0.1" euler="0 90 0"/>
      <geom name="box" type="box" size="0.03 0.02 0.01" pos="0 0.1 0" euler="30 0 45"/>
      <geom name="cyl" type="cylinder" size="0.01 0.02"/>
      <geom name="cap" type="capsule" size="0.01 0.02" pos="-0.1 0 0" quat="0.7071068 0.7071068 0 0"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_geom_elements_match_primitives():
    model = mujoco.MjModel.from_xml_string(PRIMS_XML)
    h = 0.01
    direct = {"sph": surface.sphere(0.02, h), "ell": surface.ellipsoid([0.03, 0.02, 0.01], h),
              "box": surface.box([0.03, 0.02, 0.01], h), "cyl": surface.cylinder(0.01, 0.02, h),
              "cap": surface.capsule(0.01, 0.02, h)}
    for name, el in direct.items():
        got = surface.geom_elements(model, model.geom(name).id, h)
        assert np.array_equal(got.centroids, el.centroids) and np.array_equal(got.areas, el.areas), name
        assert np.array_equal(got.normals, el.normals), name


def test_body_elements_places_geoms_in_body_frame():
    model = mujoco.MjModel.from_xml_string(PRIMS_XML)
    h = 0.01
    el = surface.body_elements(model, model.body("b").id, h)
    parts = [surface.geom_elements(model, g, h) for g in range(1, model.ngeom)]    # the plane is skipped
    assert len(el) == sum(map(len, parts))
    assert el.area() == pytest.approx(sum(p.area() for p in parts))
    # The sphere's elements are centred on its geom_pos; the rotated box faces stay unit and outward
    # about the box centre.
    n_sph, n_ell, n_box = len(parts[0]), len(parts[1]), len(parts[2])
    sph = el.centroids[:n_sph]
    assert np.allclose(sph.T @ el.areas[:n_sph] / el.areas[:n_sph].sum(), [0.1, -0.05, 0.02], atol=1e-12)
    assert np.allclose(np.linalg.norm(sph - [0.1, -0.05, 0.02], axis=1), 0.02)
    box = slice(n_sph + n_ell, n_sph + n_ell + n_box)
    rel = el.centroids[box] - model.geom_pos[model.geom("box").id]
    assert np.all(np.einsum("ij,ij->i", rel, el.normals[box]) > 0)
    # Against MuJoCo's own pose: world points = xpos + xmat @ local match geom_xpos + geom_xmat @ geom-local.
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    b = model.body("b").id
    world = el.transformed(data.xpos[b], data.xmat[b].reshape(3, 3))
    start = 0
    for g, p in zip(range(1, model.ngeom), parts):
        ref = p.transformed(data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3))
        assert np.allclose(world.centroids[start:start + len(p)], ref.centroids, atol=1e-12)
        assert np.allclose(world.normals[start:start + len(p)], ref.normals, atol=1e-12)
        start += len(p)


def test_body_elements_with_mesh_and_world_body():
    model = mesh_model()
    el = surface.body_elements(model, model.body("b").id, 0.01)
    exact = 8 * (0.01 * 0.02 + 0.02 * 0.03 + 0.01 * 0.03) + 4 * math.pi * 0.02**2
    assert el.area() == pytest.approx(exact, rel=1e-6)
    floor_only = mujoco.MjModel.from_xml_string(PRIMS_XML)
    assert len(surface.body_elements(floor_only, 0, 0.01)) == 0    # world body: only the plane
    with pytest.raises(ValueError, match="body_id must be in 0..1, got 5"):
        surface.body_elements(floor_only, 5, 0.01)


def test_unsupported_geom_raises_with_name_and_types():
    model = mujoco.MjModel.from_xml_string(PRIMS_XML)
    with pytest.raises(ValueError, match=r"geom 'floor' \(id 0\) has type 'plane'.*terrain.*supported types: "
                                         r"sphere, ellipsoid, box, cylinder, capsule, mesh"):
        surface.geom_elements(model, 0, 0.01)
    with pytest.raises(ValueError, match="geom_id must be in"):
        surface.geom_elements(model, model.ngeom, 0.01)


def test_body_elements_skip_visual_geoms_over_collision_geoms():
    xml = """<mujoco><worldbody><body name="b">
      <geom type="sphere" size="0.02"/>
      <geom type="sphere" size="0.025" contype="0" conaffinity="0" group="1"/>
    </body><body name="v" pos="1 0 0"><geom type="sphere" size="0.02" contype="0" conaffinity="0"/></body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    only_collision = surface.body_elements(model, model.body("b").id, 0.01)
    assert only_collision.area() == pytest.approx(4 * np.pi * 0.02**2)
    only_visual = surface.body_elements(model, model.body("v").id, 0.01)
    assert only_visual.area() == pytest.approx(4 * np.pi * 0.02**2)


# --- culling: surface inside another geom of the same body ------------------------------------------------
CULL_SIZES = (0.01, 0.005, 0.0025)
CULL_C = 0.5     # |exposed area error| <= CULL_C * size * (length of the intersection curves); measured <= 0.26


def one_body(geoms, assets=""):
    model = mujoco.MjModel.from_xml_string(
        f"<mujoco><asset>{assets}</asset><worldbody><body name='b' pos='0.1 0.2 0.3' euler='10 20 30'>"
        f"{geoms}</body></worldbody></mujoco>")
    return model, model.body("b").id


R1, R2, L1, L2 = 0.03, 0.02, 0.08, 0.07     # two capsules end to end along z, radius R1 then R2
_Z0 = math.sqrt(R1**2 - R2**2)             # R2's side is inside R1's end ball up to here
BA, BB, BC, BX, BY = 0.05, 0.0213, 0.0171, 0.0037, -0.0051    # cube a, small box (b, b, c) at (x, y, a)
SCENES = {
    # name: (geoms, exact exposed area m^2, length m of the intersection curves counted on both surfaces)
    "two spheres": ("<geom type='sphere' size='0.05'/><geom type='sphere' size='0.05' pos='0.06 0 0'/>",
                    2 * (4 * math.pi * 0.05**2 - 2 * math.pi * 0.05 * (0.05 - 0.03)),
                    2 * 2 * math.pi * math.sqrt(0.05**2 - 0.03**2)),
    "sphere inside capsule": ("<geom type='capsule' size='0.03 0.05'/><geom type='sphere' size='0.02' "
                              "pos='0.005 0 0.03'/>", 2 * math.pi * 0.03 * 0.1 + 4 * math.pi * 0.03**2, 0.0),
    "capsules end to end": (f"<geom type='capsule' fromto='0 0 {-L1} 0 0 0' size='{R1}'/>"
                            f"<geom type='capsule' fromto='0 0 0 0 0 {L2}' size='{R2}'/>",
                            # R1: side, far end, the near end ball less its polar cap of radius R2;
                            # R2: side beyond _Z0, far end (its near end ball is inside R1's)
                            2 * math.pi * R1 * (L1 + R1 + _Z0) + 2 * math.pi * R2 * (L2 - _Z0 + R2),
                            2 * 2 * math.pi * R2),
    "box poking out of a box": (f"<geom type='box' size='{BA} {BA} {BA}'/><geom type='box' size='{BB} {BB} "
                                f"{BC}' pos='{BX} {BY} {BA}'/>",
                                # the cube less the covered 2b x 2b patch, the small box's part above
                                24 * BA**2 - 4 * BB**2 + 4 * BB**2 + 8 * BB * BC, 2 * 8 * BB),
}


@pytest.mark.parametrize("name", SCENES)
def test_culled_area_matches_analytic_exposed_area(name):
    geoms, exact, curves = SCENES[name]
    model, b = one_body(geoms)
    for h in CULL_SIZES:
        kept = surface.body_elements(model, b, h)
        err = abs(kept.area() - exact)
        assert err <= CULL_C * h * curves + 1e-12 * exact, (name, h, err / exact)
        full = surface.body_elements(model, b, h, cull=False)
        assert abs(full.area() - exact) > 2 * (CULL_C * h * curves + 1e-12 * exact)   # culling matters here


def test_culling_with_meshes_convex_and_not():
    # a sphere half sunk into the top face of a box mesh: its lower half and a disc of the face go
    he, r = (0.03, 0.02, 0.012), 0.01
    box_v = " ".join(f"{x * he[0]} {y * he[1]} {z * he[2]}" for x in (-1, 1) for y in (-1, 1) for z in (-1, 1))
    model, b = one_body(f"<geom type='mesh' mesh='m'/><geom type='sphere' size='{r}' pos='0.004 -0.003 {he[2]}'/>",
                        f"<mesh name='m' vertex='{box_v}'/>")
    exact = 8 * (he[0] * he[1] + he[1] * he[2] + he[0] * he[2]) + math.pi * r * r
    for h in CULL_SIZES:
        assert abs(surface.body_elements(model, b, h).area() - exact) <= CULL_C * h * 4 * math.pi * r + 1e-6 * exact
    # an L-shaped prism (non-convex) and a ball in its notch: inside the hull, outside the mesh: all kept
    xy = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], dtype=float) * 0.03
    v = np.concatenate([np.column_stack([xy, np.full(6, -0.015)]), np.column_stack([xy, np.full(6, 0.015)])])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]
    f = [(a + 6, b_ + 6, c + 6) for a, b_, c in fan] + [(a, c, b_) for a, b_, c in fan]
    f += [t for i in range(6) for t in ((i, (i + 1) % 6, (i + 1) % 6 + 6), (i, (i + 1) % 6 + 6, i + 6))]
    asset = (f"<mesh name='L' vertex='{' '.join(map(str, v.ravel()))}' "
             f"face='{' '.join(map(str, np.ravel(f)))}'/>")
    for pos, hidden in (("0.038 0.038 0", 0.0), ("0.015 0.015 0", 4 * math.pi * 0.006**2)):
        model, b = one_body(f"<geom type='mesh' mesh='L'/><geom type='sphere' size='0.006' pos='{pos}'/>", asset)
        kept, culled = surface.body_elements_with_culled(model, b, 0.005)
        assert culled.area() == pytest.approx(hidden, rel=1e-9, abs=1e-15), pos
    model, b = one_body("<geom type='mesh' mesh='L'/><geom type='sphere' size='0.006' pos='0.038 0.038 0'/>", asset)
    n_ball = len(surface.geom_elements(model, 1, 0.005))
    ball = surface.body_elements(model, b, 0.005, cull=False).centroids[-n_ball:]
    # the run-time meaning (convex hull, what MuJoCo collides with) would hide the ball in the notch
    assert occlusion.occluded(ball, occlusion.geom_occluders(model, b)[:1]).all()


def test_single_geom_bodies_are_unchanged_bit_for_bit():
    for xml in ("<geom type='sphere' size='0.02'/>", "<geom type='capsule' size='0.01 0.03'/>",
                "<geom type='box' size='0.03 0.02 0.01' pos='0.1 0 0' euler='0 30 0'/>",
                # a visual-only geom over it is not part of the surface, so it culls nothing either
                "<geom type='sphere' size='0.02'/><geom type='sphere' size='0.05' contype='0' conaffinity='0'/>"):
        model, b = one_body(xml)
        new, old = surface.body_elements(model, b, 0.005), surface.body_elements(model, b, 0.005, cull=False)
        for a in ("centroids", "normals", "areas"):
            assert np.array_equal(getattr(new, a), getattr(old, a)), (xml, a)
        assert len(surface.body_elements_with_culled(model, b, 0.005)[1]) == 0
    for path in ("sand_swimmer.xml", "quadruped.xml"):
        model = mujoco.MjModel.from_xml_path(os.path.join(MODELS, path))
        for b in range(model.nbody):
            new, old = surface.body_elements(model, b, 0.01), surface.body_elements(model, b, 0.01, cull=False)
            assert all(np.array_equal(getattr(new, a), getattr(old, a)) for a in ("centroids", "normals", "areas"))


def test_kept_and_culled_partition_the_full_surface():
    geoms = SCENES["capsules end to end"][0] + "<geom type='sphere' size='0.01' pos='0 0 -0.04'/>"
    model, b = one_body(geoms)
    full = surface.body_elements(model, b, 0.005, cull=False)
    kept, culled = surface.body_elements_with_culled(model, b, 0.005)
    assert len(kept) + len(culled) == len(full)
    assert kept.area() + culled.area() == pytest.approx(full.area(), rel=1e-12)
    key = lambda el: np.sort(np.column_stack([el.centroids, el.normals, el.areas]).view("f8,f8,f8,f8,f8,f8,f8"), axis=0)
    both = Elements.concatenate([kept, culled])
    assert np.array_equal(key(both), key(full))
    # the small sphere lies wholly inside the R1 capsule: every one of its elements is culled
    assert culled.area() >= 4 * math.pi * 0.01**2
    assert np.array_equal(surface.body_elements(model, b, 0.005).centroids, kept.centroids)


def test_nested_touching_and_coincident_geoms():
    sphere_area = lambda r: 4 * math.pi * r * r
    # nested: only the outermost remains
    model, b = one_body("<geom type='sphere' size='0.01'/><geom type='sphere' size='0.03'/>"
                        "<geom type='sphere' size='0.02' pos='0.005 0 0'/>")
    assert surface.body_elements(model, b, 0.005).area() == pytest.approx(sphere_area(0.03), rel=1e-12)
    # tangent spheres and a box standing on a box: surfaces touch, nothing is inside, nothing is culled
    for xml in ("<geom type='sphere' size='0.02'/><geom type='sphere' size='0.02' pos='0.04 0 0'/>",
                "<geom type='box' size='0.02 0.02 0.02'/><geom type='box' size='0.01 0.01 0.01' pos='0 0 0.03'/>"):
        model, b = one_body(xml)
        assert len(surface.body_elements_with_culled(model, b, 0.005)[1]) == 0, xml
    # two identical geoms: each lies on, not inside, the other; both copies stay (documented), never none
    model, b = one_body("<geom type='sphere' size='0.02'/><geom type='sphere' size='0.02'/>")
    assert surface.body_elements(model, b, 0.005).area() == pytest.approx(2 * sphere_area(0.02), rel=1e-12)


def test_load_mesh_reads_a_mesh_file_like_mesh(tmp_path):
    """A mesh file (through trimesh) gives the elements of the same vertices and faces given directly."""
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    path = tmp_path / "box.stl"
    box.export(path)
    got = surface.load_mesh(path, 0.01)
    ref = surface.mesh(np.asarray(box.vertices), np.asarray(box.faces), 0.01)
    assert len(got) == len(ref)
    np.testing.assert_allclose(got.area(), 2 * (0.1 * 0.06 + 0.1 * 0.04 + 0.06 * 0.04), rtol=1e-6)
    np.testing.assert_allclose(got.enclosed_volume(), 0.1 * 0.06 * 0.04, rtol=1e-6)
    empty = tmp_path / "empty.obj"
    empty.write_text("v 0 0 0\n")
    with pytest.raises(ValueError, match="no triangles"):
        surface.load_mesh(empty)
