"""Occlusion: inside_geom against brute-force references, mesh hulls and non-convex meshes, body
occluders, and the hidden surface of the bundled robots."""

import math
import os

import mujoco
import numpy as np
import pytest
from scipy import spatial

from rft_mujoco.geometry import occlusion
from rft_mujoco.geometry import surface
from rft_mujoco.models import __file__ as _models_init

G = mujoco.mjtGeom
TOL = occlusion.OCCLUSION_TOL
MODELS = os.path.dirname(_models_init)


# --- brute-force references ------------------------------------------------------------------------
# Plain, point-by-point predicates of the OPEN solids (margin 0), written from the definitions.
def ref_inside(p, kind, s):
    x, y, z = map(float, p)
    if kind == "sphere":
        return x * x + y * y + z * z < s[0] ** 2
    if kind == "capsule":       # a cylinder and two balls
        r, hl = s[0], s[1]
        return ((x * x + y * y < r * r and abs(z) < hl) or x * x + y * y + (z - hl) ** 2 < r * r
                or x * x + y * y + (z + hl) ** 2 < r * r)
    if kind == "cylinder":
        return x * x + y * y < s[0] ** 2 and abs(z) < s[1]
    if kind == "box":
        return abs(x) < s[0] and abs(y) < s[1] and abs(z) < s[2]
    if kind == "ellipsoid":
        return (x / s[0]) ** 2 + (y / s[1]) ** 2 + (z / s[2]) ** 2 < 1
    if kind == "octahedron":
        return abs(x) / s[0] + abs(y) / s[1] + abs(z) / s[2] < 1
    raise AssertionError(kind)


def _grid(n):
    return (np.arange(n) + 0.5) / n


def surface_samples(kind, s, spacing):
    """(m, 3) points on the surface, every surface point within ``spacing`` of one of them."""
    def ellipsoid(abc, theta_range=(0, math.pi), z0=0.0):
        big = max(abc)
        nt = math.ceil((theta_range[1] - theta_range[0]) * big / spacing) + 1
        nphi = math.ceil(2 * math.pi * big / spacing)
        t = np.linspace(*theta_range, nt)[:, None]
        ph = np.linspace(0, 2 * math.pi, nphi, endpoint=False)[None, :]
        pts = np.stack([abc[0] * np.sin(t) * np.cos(ph), abc[1] * np.sin(t) * np.sin(ph),
                        abc[2] * np.cos(t) + z0 + 0 * ph], axis=-1)
        return pts.reshape(-1, 3)

    def side(r, hl):
        nphi, nz = math.ceil(2 * math.pi * r / spacing), math.ceil(2 * hl / spacing) + 1
        ph, zz = np.meshgrid(np.linspace(0, 2 * math.pi, nphi, endpoint=False), np.linspace(-hl, hl, nz))
        return np.stack([r * np.cos(ph), r * np.sin(ph), zz], axis=-1).reshape(-1, 3)

    def disc(r, z):
        out = [np.array([[0.0, 0.0, z]])]
        for rho in np.linspace(0, r, math.ceil(r / spacing) + 1)[1:]:
            ph = np.linspace(0, 2 * math.pi, math.ceil(2 * math.pi * rho / spacing), endpoint=False)
            out.append(np.stack([rho * np.cos(ph), rho * np.sin(ph), np.full(ph.size, z)], axis=1))
        return np.concatenate(out)

    if kind == "sphere":
        return ellipsoid([s[0]] * 3)
    if kind == "ellipsoid":
        return ellipsoid(s)
    if kind == "capsule":
        r, hl = s[0], s[1]
        return np.concatenate([side(r, hl), ellipsoid([r] * 3, (0, math.pi / 2), hl),
                               ellipsoid([r] * 3, (math.pi / 2, math.pi), -hl)])
    if kind == "cylinder":
        return np.concatenate([side(s[0], s[1]), disc(s[0], s[1]), disc(s[0], -s[1])])
    if kind == "box":
        out = []
        for k in range(3):
            i, j = (k + 1) % 3, (k + 2) % 3
            gi, gj = np.meshgrid(np.linspace(-s[i], s[i], math.ceil(2 * s[i] / spacing) + 1),
                                 np.linspace(-s[j], s[j], math.ceil(2 * s[j] / spacing) + 1))
            for sign in (-1, 1):
                p = np.zeros((gi.size, 3))
                p[:, i], p[:, j], p[:, k] = gi.ravel(), gj.ravel(), sign * s[k]
                out.append(p)
        return np.concatenate(out)
    if kind == "octahedron":
        out = []
        for sx in (-1, 1):
            for sy in (-1, 1):
                for sz in (-1, 1):
                    a, b, c = np.diag([sx * s[0], sy * s[1], sz * s[2]])
                    n = math.ceil(max(np.linalg.norm(a - b), np.linalg.norm(b - c), np.linalg.norm(a - c))
                                  / spacing) + 1
                    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
                    keep = u + v <= 1
                    u, v = u[keep][:, None], v[keep][:, None]
                    out.append(a + u * (b - a) + v * (c - a))
        return np.concatenate(out)
    raise AssertionError(kind)


def ref_depth(points, kind, s, spacing):
    """Signed distance to the surface (+ inside), by nearest dense surface sample; error <= spacing."""
    tree = spatial.cKDTree(surface_samples(kind, s, spacing))
    d, _ = tree.query(points)
    sign = np.array([1.0 if ref_inside(p, kind, s) else -1.0 for p in points])
    return sign * d


PRIMS = {
    "sphere": (G.mjGEOM_SPHERE, [0.03, 0, 0]),
    "capsule": (G.mjGEOM_CAPSULE, [0.02, 0.04, 0]),
    "cylinder": (G.mjGEOM_CYLINDER, [0.03, 0.02, 0]),
    "box": (G.mjGEOM_BOX, [0.04, 0.03, 0.02]),
    "ellipsoid": (G.mjGEOM_ELLIPSOID, [0.05, 0.03, 0.02]),
}
SPACING = 4e-4          # surface samples of the depth reference, m
MARGIN = 3e-3           # a visible margin, m


def half_extents(kind, s):
    """(3,) half-extents of the solid's bounding box."""
    return {"sphere": [s[0]] * 3, "capsule": [s[0], s[0], s[0] + s[1]], "cylinder": [s[0], s[0], s[1]]
            }.get(kind, list(s[:3]))


def random_points(kind, s, n, seed):
    """(n + 20, 3): uniform in 1.3 x the bounding box (inside and near outside), and 20 far away."""
    rng = np.random.default_rng(seed)
    ext = 1.3 * np.array(half_extents(kind, s))
    far = rng.normal(size=(20, 3)) * 10.0
    return np.concatenate([rng.uniform(-ext, ext, size=(n, 3)), far])


def on_surface(kind, s, seed):
    """(m, 3) surface points with outward normals, away from edges: from surface.geom_elements-style
    exact constructions (element centroids lie on the surface)."""
    h = 0.006
    el = {"sphere": lambda: surface.sphere(s[0], h), "capsule": lambda: surface.capsule(s[0], s[1], h),
          "cylinder": lambda: surface.cylinder(s[0], s[1], h), "box": lambda: surface.box(s, h),
          "ellipsoid": lambda: surface.ellipsoid(s, h)}[kind]()
    return el.centroids, el.normals


@pytest.mark.parametrize("kind", PRIMS)
def test_inside_geom_matches_brute_force(kind):
    t, s = PRIMS[kind]
    p = random_points(kind, s, 1500, seed=list(PRIMS).index(kind))
    # margin 0: the open solid, against the plain predicates (points are never exactly on the surface)
    ref = np.array([ref_inside(q, kind, s) for q in p])
    got = occlusion.inside_geom(p, t, s, margin=0.0)
    assert 200 < ref.sum() < len(p) - 200          # both outcomes are well represented
    assert np.array_equal(got, ref)
    # a visible margin: inside iff deeper than it, against the dense-sample depth (outside its error band)
    depth = ref_depth(p, kind, s, SPACING)
    got = occlusion.inside_geom(p, t, s, margin=MARGIN)
    clear = np.abs(depth - MARGIN) > SPACING
    want = depth > MARGIN
    if kind == "ellipsoid":
        # The shrunken-ellipsoid test: deeper than the margin is always inside, on or outside the surface
        # never; between, it may differ from the true depth (documented approximation): rarely here.
        assert np.all(got[clear & want]) and not np.any(got[depth < 0])
        assert np.count_nonzero((got != want) & clear) <= 0.02 * len(p)
    else:
        assert np.array_equal(got[clear], want[clear])
    assert np.count_nonzero(~clear) < 0.05 * len(p)


@pytest.mark.parametrize("kind", PRIMS)
def test_inside_geom_on_and_near_the_surface(kind):
    t, s = PRIMS[kind]
    c, n = on_surface(kind, s, 0)
    assert np.allclose([ref_depth(c[:50], kind, s, 1e-3)], 0, atol=1e-3)    # they are surface points
    assert not occlusion.inside_geom(c, t, s).any()                          # on: not inside
    assert occlusion.inside_geom(c - 2 * TOL * n, t, s).all()                 # 2 tol deep: inside
    assert not occlusion.inside_geom(c - 0.5 * TOL * n, t, s).any()           # 0.5 tol deep: not
    assert not occlusion.inside_geom(c + 2 * TOL * n, t, s).any()             # outside
    assert occlusion.inside_geom(c - 2 * TOL * n, t, s, margin=0.0).all()


def test_terrain_never_occludes_and_errors_say_what_was_given():
    p = np.zeros((3, 3))
    for t in (G.mjGEOM_PLANE, G.mjGEOM_HFIELD):
        assert not occlusion.inside_geom(p, t, [1, 1, 1]).any()
    with pytest.raises(ValueError, match=r"points must be an \(n, 3\).*got shape \(3,\)"):
        occlusion.inside_geom([0, 0, 0], G.mjGEOM_SPHERE, [1])
    with pytest.raises(ValueError, match=r"size of a capsule .*got shape \(1,\)"):
        occlusion.inside_geom(p, G.mjGEOM_CAPSULE, [0.1])
    with pytest.raises(ValueError, match=r"size of a box needs 3 positive.*-1.0"):
        occlusion.inside_geom(p, G.mjGEOM_BOX, [0.1, -1, 0.1])
    with pytest.raises(ValueError, match="margin must be a finite length >= 0 in m, got -0.1"):
        occlusion.inside_geom(p, G.mjGEOM_SPHERE, [1], margin=-0.1)
    with pytest.raises(ValueError, match="'sdf' has no inside test"):
        occlusion.inside_geom(p, G.mjGEOM_SDF, [1, 1, 1])
    with pytest.raises(ValueError, match="mesh geom needs mesh_halfspaces"):
        occlusion.inside_geom(p, G.mjGEOM_MESH, [0, 0, 0])
    with pytest.raises(ValueError, match=r"\(k, 4\).*got shape \(4, 3\)"):
        occlusion.inside_geom(p, G.mjGEOM_MESH, [0, 0, 0], mesh_halfspaces=np.zeros((4, 3)))
    with pytest.raises(ValueError, match="span no volume"):
        occlusion.mesh_halfspaces([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])


# --- meshes: convex hulls from inline MJCF ---------------------------------------------------------
BOX_HE, OCTA = (0.03, 0.02, 0.012), (0.04, 0.03, 0.02)
BOX_POS, BOX_QUAT = np.array([0.1, -0.02, 0.03]), np.array([0.9, 0.1, -0.3, 0.2])
OCTA_POS, OCTA_QUAT = np.array([-0.05, 0.04, 0.0]), np.array([0.7, 0.0, 0.5, -0.3])


def _quat_mat(q):
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, dtype=float) / np.linalg.norm(q))
    return m.reshape(3, 3)


def mesh_model():
    box_v = " ".join(f"{x * BOX_HE[0]} {y * BOX_HE[1]} {z * BOX_HE[2]}"
                     for x in (-1, 1) for y in (-1, 1) for z in (-1, 1))
    a, b, c = OCTA
    octa_v = f"{a} 0 0 {-a} 0 0 0 {b} 0 0 {-b} 0 0 0 {c} 0 0 {-c}"
    q = lambda v: " ".join(map(str, v / np.linalg.norm(v)))
    xml = f"""<mujoco><asset><mesh name="box" vertex="{box_v}"/><mesh name="octa" vertex="{octa_v}"/></asset>
      <worldbody><body name="b" pos="0.2 0.3 0.4" quat="0.8 0.2 0.1 0.3">
        <geom name="box" type="mesh" mesh="box" pos="{' '.join(map(str, BOX_POS))}" quat="{q(BOX_QUAT)}"/>
        <geom name="octa" type="mesh" mesh="octa" pos="{' '.join(map(str, OCTA_POS))}" quat="{q(OCTA_QUAT)}"/>
      </body></worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def test_mesh_hulls_match_the_analytic_solids_in_the_body_frame():
    """MuJoCo recentres and re-orients mesh frames; the occluders must still be the solids of the MJCF."""
    model = mesh_model()
    occ = {o.geom_id: o for o in occlusion.geom_occluders(model, model.body("b").id)}
    box, octa = occ[model.geom("box").id], occ[model.geom("octa").id]
    assert len(box.halfspaces) == 6 and len(octa.halfspaces) == 8      # coplanar hull triangles merged
    assert box.triangles is None and octa.triangles is None             # convex: the hull is exact
    for o, kind, s, pos, quat in ((box, "box", BOX_HE, BOX_POS, BOX_QUAT),
                                  (octa, "octahedron", OCTA, OCTA_POS, OCTA_QUAT)):
        mat = _quat_mat(quat)
        local = random_points(kind, s, 1500, seed=7)
        body = pos + local @ mat.T
        ref = np.array([ref_inside(q, kind, s) for q in local])
        assert np.array_equal(o.contains(body, margin=0.0), ref), kind
        depth = ref_depth(local, kind, s, SPACING)
        clear = np.abs(depth - MARGIN) > SPACING
        assert np.array_equal(o.contains(body, margin=MARGIN)[clear], (depth > MARGIN)[clear]), kind
        # surface points (vertices and face points, float32 in MuJoCo): not inside by default
        surf = pos + surface_samples(kind, s, 0.01) @ mat.T
        assert not o.contains(surf).any(), kind
        assert o.contains(pos + 0.999 * (surf - pos)).all() or kind == "box"   # just inside, off-edges
        assert o.contains(pos + 0.9 * (surf - pos)).all(), kind


def test_occluders_are_posed_like_mujoco_and_follow_the_surface_rule():
    model = mesh_model()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    b = model.body("b").id
    for o in occlusion.geom_occluders(model, b):
        w = o.transformed(data.xpos[b], data.xmat[b])
        assert np.allclose(w.pos, data.geom_xpos[o.geom_id], atol=1e-12)
        assert np.allclose(w.mat, data.geom_xmat[o.geom_id].reshape(3, 3), atol=1e-12)
    xml = """<mujoco><worldbody><geom type="plane" size="1 1 1"/>
      <body name="mixed"><geom name="c" type="sphere" size="0.02"/>
        <geom name="v" type="sphere" size="0.05" contype="0" conaffinity="0"/></body>
      <body name="visual" pos="1 0 0"><geom name="v1" type="sphere" size="0.02" contype="0" conaffinity="0"/>
        <geom name="v2" type="box" size="0.01 0.01 0.01" contype="0" conaffinity="0"/></body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    names = lambda b: [model.geom(o.geom_id).name for o in occlusion.geom_occluders(model, model.body(b).id)]
    assert names("mixed") == ["c"]                 # the visual sphere around it hides nothing
    assert names("visual") == ["v1", "v2"]
    assert occlusion.geom_occluders(model, 0) == []      # world: only the plane (terrain)


def test_occluded_skips_the_owner_geom():
    model = mujoco.MjModel.from_xml_string("""<mujoco><worldbody><body name="b">
      <geom name="s1" type="sphere" size="0.05"/><geom name="s2" type="sphere" size="0.05" pos="0.06 0 0"/>
    </body></worldbody></mujoco>""")
    occ = occlusion.geom_occluders(model, model.body("b").id)
    p = np.array([[0.03, 0, 0], [0.03, 0, 0], [0.03, 0, 0], [-0.04, 0, 0]])     # in both; in s1 only
    s1, s2 = model.geom("s1").id, model.geom("s2").id
    assert occlusion.occluded(p, occ, owner=np.array([s1, s2, -1, s1])).tolist() == [True, True, True, False]
    assert occlusion.occluded(p, occ).tolist() == [True, True, True, True]
    with pytest.raises(ValueError, match=r"owner must be an \(n,\) int array.*n = 4.*got shape \(3,\)"):
        occlusion.occluded(p, occ, owner=np.array([0, 0, 0]))


# --- a non-convex mesh: an L-shaped prism -------------------------------------------------------------
L_XY = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], dtype=float) * 0.03 - 0.03   # CCW
L_HZ = 0.015


def l_mesh():
    """(vertices, faces) of the L-prism, outward wound (the surface module's checks would raise
    otherwise)."""
    n = len(L_XY)
    v = np.concatenate([np.column_stack([L_XY, np.full(n, -L_HZ)]), np.column_stack([L_XY, np.full(n, L_HZ)])])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]      # from the reflex corner, counter-clockwise
    faces = [(a + n, b + n, c + n) for a, b, c in fan] + [(a, c, b) for a, b, c in fan]
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, j, j + n), (i, j + n, i + n)]
    return v, np.array(faces)


def ref_inside_l(p):
    x, y, z = p + 0.03
    return abs(z - 0.03) < L_HZ and ((0 < x < 0.06 and 0 < y < 0.03) or (0 < x < 0.03 and 0 < y < 0.06))


def l_model(extra=""):
    v, f = l_mesh()
    xml = f"""<mujoco><asset><mesh name="L" vertex="{' '.join(map(str, v.ravel()))}"
                                       face="{' '.join(map(str, f.ravel()))}"/></asset>
      <worldbody><body name="b"><geom name="L" type="mesh" mesh="L"/>{extra}</body></worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def test_non_convex_mesh_exact_test_and_its_hull():
    model = l_model()
    el = surface.geom_elements(model, 0, 0.01)          # a valid closed, outward mesh
    assert el.enclosed_volume() == pytest.approx(3 * 0.03**2 * 2 * L_HZ, rel=1e-6)
    (occ,) = occlusion.geom_occluders(model, model.body("b").id)
    assert occ.triangles is not None                    # recognised as non-convex
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.04, 0.04, size=(3000, 3))
    p[:, 2] *= 0.5
    ref = np.array([ref_inside_l(q) for q in p])
    assert np.array_equal(occ.contains(p, margin=0.0, exact_mesh=True), ref)
    hull = occ.contains(p, margin=0.0)
    assert np.all(hull[ref]) and np.any(hull & ~ref)    # the hull contains the notch too
    # near the faces: 2 tol below the top face inside, 0.5 tol below not (margin through face distances)
    top = np.array([[-0.02, -0.02, L_HZ], [0.02, -0.02, L_HZ], [-0.02, 0.02, L_HZ]])
    down = np.array([0, 0, 1.0])
    assert occ.contains(top - 2 * TOL * down, exact_mesh=True).all()
    assert not occ.contains(top - 0.5 * TOL * down, exact_mesh=True).any()
    # the notch's walls are not hull faces: the margin there comes from the distance to the faces
    wall = np.array([[0.015, 0.0, 0.0], [0.0, 0.02, 0.005]])      # on the walls y = 0 and x = 0
    into = np.array([[0, -1.0, 0], [-1.0, 0, 0]])                 # inward normals
    assert occ.contains(wall + 2 * TOL * into, exact_mesh=True).all()
    assert not occ.contains(wall + 0.5 * TOL * into, exact_mesh=True).any()
    assert occ.contains(wall + 0.5 * TOL * into, exact_mesh=True, margin=0.0).all()
    # inside the hull, deep, but in the notch: the exact test says outside
    notch = [[0.008, 0.008, 0.0]]
    assert occ.contains(notch).all() and not occ.contains(notch, exact_mesh=True).any()


# --- the bundled robots ----------------------------------------------------------------------------
def hidden_fractions(path, key, size):
    """(same-body, cross-body) hidden fractions of the total un-culled area at the model's pose: same-body
    from surface.body_elements_with_culled, cross-body = elements inside another body's geom (world
    frame, convex hulls), from occlusion.occluded."""
    model = mujoco.MjModel.from_xml_path(os.path.join(MODELS, path))
    data = mujoco.MjData(model)
    if key is not None:
        mujoco.mj_resetDataKeyframe(model, data, model.key(key).id)
    mujoco.mj_kinematics(model, data)
    world = [(b, o.transformed(data.xpos[b], data.xmat[b]))
             for b in range(model.nbody) for o in occlusion.geom_occluders(model, b)]
    total = same = cross = 0.0
    for b in range(1, model.nbody):
        full = surface.body_elements(model, b, size, cull=False)
        kept, culled = surface.body_elements_with_culled(model, b, size)
        if len(culled) == 0:          # nothing hidden inside the body: the elements are the same arrays
            assert all(np.array_equal(getattr(kept, a), getattr(full, a)) for a in ("centroids", "normals", "areas"))
        el = full.transformed(data.xpos[b], data.xmat[b])
        total += full.area()
        same += culled.area()
        cross += el.areas[occlusion.occluded(el.centroids, [o for bb, o in world if bb != b])].sum()
    return same / total, cross / total


def test_swimmer_hidden_surface():
    """Measured: same-body 0 (one capsule per body); cross-body at the straight pose 27.0% at 10 mm
    (the 4-7 mm capsules keep their minimum tessellation), 36.2% at 5 mm, 31.9% at 2 mm, 32.6% at 1 mm;
    analytic 33.18% (collinear capsules sharing end points, radii tapering: at each joint the thinner
    link's front cap and its side up to sqrt(r_a^2 - r_b^2) are inside the thicker one's cap, and the
    thicker cap's polar part of radius r_b inside the thinner cylinder)."""
    r = [0.0070, 0.0068, 0.0064, 0.0059, 0.0053, 0.0047, 0.0040]
    length = [0.025] + [0.017] * 6
    full = sum(2 * math.pi * a * l + 4 * math.pi * a * a for a, l in zip(r, length))
    hidden = sum(2 * math.pi * a * (a - math.sqrt(a * a - b * b)) + 2 * math.pi * b * b
                 + 2 * math.pi * b * math.sqrt(a * a - b * b) for a, b in zip(r[:-1], r[1:]))
    curves = sum(2 * 2 * math.pi * b for b in r[1:])        # intersection circles, on both surfaces
    size = 0.002
    same, cross = hidden_fractions("sand_swimmer.xml", None, size)
    print(f"swimmer: same-body {same:.2%}, cross-body {cross:.2%} at {size} m; analytic {hidden / full:.2%}")
    assert same == 0.0
    assert abs(cross - hidden / full) * full < 0.5 * size * curves
    assert 0.28 < cross < 0.36


def test_quadruped_hidden_surface():
    """Measured at keyframe 'home': same-body 0 (one geom per body; the foot sphere is its own body,
    welded to the calf); cross-body 14.2% at 10 mm, 14.3% at 5 mm, 13.9% at 2 mm, 13.8% at 1 mm."""
    same, cross = hidden_fractions("quadruped.xml", "home", 0.005)
    print(f"quadruped: same-body {same:.2%}, cross-body {cross:.2%} at 0.005 m")
    assert same == 0.0
    assert 0.12 < cross < 0.16
