"""The package's import structure (docs/architecture.md, "What imports what"): imports go down the layers and
never up, and no two modules import each other, directly or through others, function-local imports included."""

import ast
import pathlib

import pytest

import rft_mujoco

PACKAGE = pathlib.Path(rft_mujoco.__file__).parent
LAYERS = {"tol": 0, "tables": 0, "physics": 1, "geometry": 2, "compiled": 3, "coupling": 4, "forces": 5}
"""The layer of each top-level part; the others (studies, envs, train, models, warp, the package's own
``__init__`` and ``__main__``) sit on top. A module may import its own layer's modules and lower layers'."""


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = ("rft_mujoco",) + path.relative_to(PACKAGE).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _imports(modules: dict[str, pathlib.Path]) -> dict[str, set[str]]:
    """Each module's imports of the package's modules (at any depth of its code), resolved to the nearest
    module that exists; a module's import of its own package is left out (Python runs the package first)."""
    edges = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        found = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([base] if base else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            for t in targets:
                while t and t not in modules:
                    t = t.rsplit(".", 1)[0] if "." in t else ""
                if t and t != name and not name.startswith(t + "."):
                    found.add(t)
        edges[name] = found
    return edges


def _layer(name: str) -> int:
    parts = name.split(".")
    return LAYERS.get(parts[1], 6) if len(parts) > 1 else 6


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return out


EDGES = _imports(_modules())


def test_the_scan_sees_the_package():
    """The scan found the modules and their imports (a scan that saw nothing would pass the tests below)."""
    assert len(EDGES) > 80
    assert "rft_mujoco.physics.law" in EDGES["rft_mujoco.compiled.law"] or \
        any(t.startswith("rft_mujoco.physics") for t in EDGES["rft_mujoco.compiled.law"])
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_imports_itself_through_others():
    assert _cycles(EDGES) == []


def test_the_envs_and_models_import_no_study():
    """The environments and the bundled models stand on the library, not on the studies (issue 30: the envs
    imported ``studies.gait``; the gait is now beside its robot, ``rft_mujoco.models.quadruped``)."""
    mine = {m: t for m, t in EDGES.items() if m.split(".")[1:2] in (["envs"], ["models"])}
    assert len(mine) > 10 and "rft_mujoco.models.quadruped" in EDGES["rft_mujoco.envs.sand_quadruped_v1"]
    assert [(m, t) for m, targets in mine.items() for t in sorted(targets) if t.startswith("rft_mujoco.studies")] == []


def test_only_the_coupling_touches_a_handles_private_members():
    """A :class:`~rft_mujoco.coupling.handle.SandHandle`'s ``_``-prefixed members are its package-internal seam
    with the dispatcher, its evaluators and checks (all in ``coupling/``); studies, envs, warp and the tests use
    its public surface (settings, ``observe``, ``counters``, ``diagnostics``, ``evaluation_path``: issue 30)."""
    tree = ast.parse((PACKAGE / "coupling" / "handle.py").read_text())
    cls = next(n for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == "SandHandle")
    private = {n.name for n in ast.walk(cls) if isinstance(n, ast.FunctionDef)} | \
        {n.attr for n in ast.walk(cls) if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
         and n.value.id == "self"}
    private = {p for p in private if p.startswith("_") and not p.startswith("__")}
    assert {"_workspace", "_evaluate", "_model", "_backend_request"} <= private      # the scan saw them
    outside = [p for p in list(PACKAGE.rglob("*.py")) + list(pathlib.Path(__file__).parent.glob("*.py"))
               if p.parent != PACKAGE / "coupling"]
    found = []
    for path in outside:
        module = ast.parse(path.read_text())
        imported = {(a.asname or a.name).split(".")[0] for n in ast.walk(module)
                    if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
        found += [f"{path.name}:{n.lineno} {ast.unparse(n)}" for n in ast.walk(module)
                  if isinstance(n, ast.Attribute) and n.attr in private
                  and not (isinstance(n.value, ast.Name) and n.value.id in imported | {"self", "cls"})]
    assert len(outside) > 100 and found == []


@pytest.mark.parametrize("layer", sorted(LAYERS, key=LAYERS.get))
def test_imports_go_down_the_layers(layer):
    up = [(m, t) for m, targets in EDGES.items() if m.split(".")[1:2] == [layer] for t in sorted(targets)
          if _layer(t) > _layer(m) or (_layer(t) == _layer(m) and t.split(".")[1] != layer)]
    assert up == []


MAX_POSITIONAL, MAX_BODY_LINES = 12, 120
"""Issue 30's limits for the functions of ``rft_mujoco`` outside ``warp/`` (positional parameters, ``self`` and
``cls`` not counted; lines of body after the docstring). The 32 kernels over them when the check was written
(2026-12-03: numba kernels that took their arrays one by one) were brought within by 2026-12-04 (issue 30:
bundles instead of 40-argument calls)."""


def _function_sizes() -> dict[str, tuple[int, int]]:
    """(positional parameters, body lines) of every function of the package outside ``warp/``, by
    ``module.function`` relative to the package (nested functions by their own name)."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] == "warp":
            continue
        module = ".".join(rel.with_suffix("").parts)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args.posonlyargs + node.args.args
                positional = sum(a.arg not in ("self", "cls") for a in args)
                body = node.body
                docstring = isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str)
                start = (body[1].lineno if len(body) > 1 else body[0].end_lineno) if docstring else body[0].lineno
                size = (positional, node.end_lineno - start + 1)
                key = f"{module}.{node.name}"
                out[key] = max(out.get(key, size), size)
    return out


def test_functions_keep_within_the_limits():
    sizes = _function_sizes()
    assert len(sizes) > 500 and sizes["physics.elements.element_states"][0] == 8    # the scan measured
    assert max(v[1] for v in sizes.values()) > MAX_BODY_LINES // 2                  # ... the long ones too
    over = {k: v for k, v in sizes.items() if v[0] > MAX_POSITIONAL or v[1] > MAX_BODY_LINES}
    assert not over, f"over {MAX_POSITIONAL} positional parameters or {MAX_BODY_LINES} lines: {over}; bundle them"


def test_the_named_slots_are_the_schemas():
    """Every named index of :mod:`rft_mujoco.compiled.schema` is its field's position in its schema, and the
    compiled evaluation addresses its argument tuples by name only (no ``hc[26]``, issue 30)."""
    import re

    from rft_mujoco.compiled import schema

    groups = (("M_", [n for n, _ in schema.MJDATA_FIELDS]), ("H_", [n for n, _ in schema.HANDLE_FIELDS]),
              ("W_", [n for n, _ in schema.WORK_FIELDS]), ("P_", list(schema.PARAMS)), ("S_", list(schema.STATE)),
              ("B_", list(schema.BOOK_STATE)), ("T_", list(schema.TABLE_HEADER)), ("R_", list(schema.REGISTRY_HEADER)),
              ("E_", list(schema.REGISTRY_ENTRY)), ("ST_", list(schema.IMPLICIT_SETTINGS)))
    checked = 0
    for prefix, names in groups:
        for i, name in enumerate(names):
            assert getattr(schema, prefix + name.upper()) == i
            checked += 1
    assert checked == len(schema.HANDLE_FIELDS) + len(schema.WORK_FIELDS) + 17 + 13 + 13 + 6 + 8 + 9 + 8 + 10
    literal = re.compile(r"\b(hc|ws|md)\[\d+\]")
    for name in ("evaluate", "implicit_eval", "share", "route", "deform_route", "implicit_route"):
        text = (PACKAGE / "compiled" / f"{name}.py").read_text()
        assert not literal.findall(text), f"compiled/{name}.py indexes hc, ws or md by position"
    from rft_mujoco.compiled import rest, route, share       # the kernels' ints are the IntEnums' values
    assert (route.DONE, route.ACTUATE, route.CONTINUE, route.PYTHON, route.MONITOR) == tuple(schema.Phase)
    assert (share.NOT_FINITE, share.BAD_ACCELERATION, share.NOT_FINITE_STATE) == (
        schema.Status.NOT_FINITE, schema.Status.BAD_ACCELERATION, schema.Status.NOT_FINITE_STATE)
    assert (rest.KEPT_GROUPS, rest.KEPT_RANK) == (schema.STATE.index("kept_groups"), schema.STATE.index("kept_rank"))
    # the route table's header, the native registry, the book's and the workspace's state, the implicit
    # settings: by name in the code (their docstrings may still say ``t[T_BOOK]``)
    by_position = re.compile(r"^(?!\s*#).*\b(t|reg|st|state)\[\d+\]", re.MULTILINE)
    files = [PACKAGE / "compiled" / f"{name}.py" for name in ("route", "deform_route", "implicit_route", "native",
                                                                 "implicit", "implicit_eval")]
    files += [PACKAGE / "coupling" / f"{name}.py" for name in ("book", "dispatch", "handle", "reference",
                                                                  "workspace")]
    for path in files:
        code = "\n".join(line for line in path.read_text().splitlines() if "``" not in line)
        found = by_position.findall(code)
        assert not found, f"{path.relative_to(PACKAGE)} indexes {sorted(set(found))} by position"


def test_the_terrain_kernels_read_tp_by_name():
    """The compiled terrain kernels and warp's terrain code address a terrain's parameters by the named slots
    of :mod:`rft_mujoco.physics.terrain_spec` only (no ``tp[6]``, issue 30): one layout, both backends."""
    import re

    literal = re.compile(r"\btp\[\s*-?\d")
    named = re.compile(r"\btp\[ts\.TP_[A-Z0-9_]+\]")
    files = [("compiled", n) for n in ("terrain", "elements", "element_pass", "deform")] + \
        [("warp", n) for n in ("law", "book", "handle")]
    for part, name in files:
        text = (PACKAGE / part / f"{name}.py").read_text()
        assert named.search(text), f"{part}/{name}.py reads no named slot (the scan would see nothing)"
        assert not literal.findall(text), f"{part}/{name}.py indexes tp by position"



def test_the_cache_key_covers_what_the_kernels_freeze():
    """Every module with compiled functions, and the modules whose named slots the kernels freeze as constants,
    are hashed into the machine code cache's key (numba keys a function's cache on its own file only: a slot
    renumbered in ``physics/terrain_spec.py`` must not reuse machine code compiled with the old numbers)."""
    from rft_mujoco.compiled import jit

    compiled = {f"compiled/{p.name}" for p in (PACKAGE / "compiled").glob("*.py")
                if "njit(" in p.read_text() or "cfunc(" in p.read_text()}
    assert len(compiled) > 10
    missing = sorted((compiled | {"compiled/schema.py", "physics/terrain_spec.py"}) - set(jit.KERNEL_SOURCES))
    assert not missing, f"add {missing} to rft_mujoco.compiled.jit.KERNEL_SOURCES"
