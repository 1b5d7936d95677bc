"""The package's layers: each module imports only from its own layer or the ones below it.

Order, bottom to top (README, "Code layout"): version, errors, numerics, model, solver, config,
analysis, files, run, campaign, reports, api, cli. The root package (hpcves/__init__.py: the
version, and the API's names fetched from hpcves.api on first use) imports nothing at import time.
Read from the source with ast, function-level imports included, so a cycle cannot hide inside a
function.
"""
import ast
import pathlib

import pytest

import hpcves

LAYERS = ("version", "errors", "numerics", "model", "solver", "config", "analysis", "files", "run", "campaign",
          "reports", "api", "cli")
ROOT = pathlib.Path(hpcves.__file__).parent


def layer_of(module: str) -> str | None:
    """``hpcves.run.store`` -> ``run``; the root package (``hpcves``: the version) -> None;
    ``hpcves.__main__`` (``python -m hpcves``) -> ``cli``, the command line it starts."""
    parts = module.split(".")
    return ("cli" if parts[1] == "__main__" else parts[1]) if len(parts) > 1 else None


def modules():
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        name = ".".join(rel.parts).removesuffix(".__init__")
        yield name, path


def imports_of(path: pathlib.Path, name: str):
    """(line, imported hpcves module) for every import in the file, at any depth."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found = [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            found = [(node.lineno, f"{base}.{a.name}" if (ROOT.parent / base.replace(".", "/") / a.name).with_suffix(
                ".py").exists() or (ROOT.parent / base.replace(".", "/") / a.name).is_dir() else base)
                     for a in node.names]
        else:
            continue
        yield from ((line, m) for line, m in found if m == "hpcves" or m.startswith("hpcves."))


def test_every_module_lives_in_a_layer():
    for name, _ in modules():
        assert name == "hpcves" or layer_of(name) in LAYERS, f"{name}: not in a layer of {LAYERS}"


def test_the_root_package_imports_only_the_api_and_the_version_and_only_on_first_use():
    path = ROOT / "__init__.py"
    tree = ast.parse(path.read_text())
    at_import = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert not at_import, f"hpcves/__init__.py imports at import time: line {at_import[0].lineno}"
    assert {m for _, m in imports_of(path, "hpcves")} == {"hpcves.api", "hpcves.version"}
    import importlib.metadata

    assert hpcves.__version__ == importlib.metadata.version("hpcves")     # pyproject.toml reads it too
    import subprocess
    import sys
    code = ("import sys, hpcves; assert 'hpcves.api' not in sys.modules and 'xarray' not in sys.modules; "
            "hpcves.open_case; assert 'hpcves.api' in sys.modules; print(sorted(hpcves.API))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "open_campaign" in result.stdout


@pytest.mark.parametrize("name, path", list(modules()), ids=lambda v: v if isinstance(v, str) else "")
def test_no_module_imports_from_a_layer_above_its_own(name, path):
    if name == "hpcves":
        return                       # the root package: the test above
    rooted = [f"line {line}" for line, target in imports_of(path, name) if target == "hpcves"]
    assert not rooted, f"{name} imports the root package (whose names come from the API above it): {rooted}"
    here = LAYERS.index(layer_of(name)) if layer_of(name) else -1
    upward = [f"line {line}: {target}" for line, target in imports_of(path, name)
              if layer_of(target) is not None and LAYERS.index(layer_of(target)) > here]
    assert not upward, f"{name} ({LAYERS[here] if here >= 0 else 'root'}) imports upward: {upward}"


def test_the_modules_import_one_another_without_a_cycle():
    """Within a layer too: the graph of imports between hpcves modules has no cycle."""
    graph = {name: {t for _, t in imports_of(path, name) if t != "hpcves"} for name, path in modules()}
    state = {}

    def visit(node, trail):
        if state.get(node) == "done":
            return
        assert state.get(node) != "open", "import cycle: " + " -> ".join(trail[trail.index(node):] + [node])
        state[node] = "open"
        for target in sorted(graph.get(node, ())):
            visit(target, trail + [node])
        state[node] = "done"
    for name in sorted(graph):
        visit(name, [])
