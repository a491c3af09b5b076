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


@pytest.mark.parametrize("layer", sorted(LAYERS, key=LAYERS.get))
def test_imports_go_down_the_layers(layer):
    up = [(m, t) for m, targets in EDGES.items() if m.split(".")[1:2] == [layer] for t in sorted(targets)
          if _layer(t) > _layer(m) or (_layer(t) == _layer(m) and t.split(".")[1] != layer)]
    assert up == []
