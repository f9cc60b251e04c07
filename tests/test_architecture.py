"""The import direction of ARCHITECTURE.md, read from the source (every import statement, also
inside functions): drivers -> protocols -> engine (+ io, parallel) -> physics.

Each rule is a list of packages a layer must not import. The test parses the files with ``ast``,
so an import hidden in a function body counts too.
"""
import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1] / "pardem"

# layer (path under pardem/) -> modules it must not import (prefix match on the dotted name)
FORBIDDEN = {
    "physics": ["mpi4py", "h5py", "meshio", "pardem.engine", "pardem.protocols", "pardem.drivers",
                "pardem.parallel", "pardem.io", "pardem.domains", "pardem.config"],
    "domains": ["mpi4py", "h5py", "meshio", "pardem.engine", "pardem.protocols", "pardem.drivers",
                "pardem.parallel", "pardem.io"],
    "engine": ["mpi4py", "h5py", "meshio", "pardem.protocols", "pardem.drivers"],
    "parallel": ["h5py", "meshio", "pardem.engine.simulation", "pardem.protocols", "pardem.drivers",
                 "pardem.io"],
    "io": ["mpi4py", "pardem.protocols", "pardem.drivers", "pardem.engine.simulation"],
    "protocols": ["mpi4py", "h5py", "meshio", "pardem.drivers"],
    "drivers": ["mpi4py", "h5py"],
    "config.py": ["mpi4py", "h5py", "meshio", "pardem.engine", "pardem.protocols", "pardem.drivers",
                  "pardem.parallel", "pardem.io"],
    "triggers.py": ["mpi4py", "h5py", "meshio", "pardem"],
}
# where mpi4py may be imported at all
MPI_HOME = "parallel"


def imports(path):
    """Dotted names imported by one file (absolute imports only; pardem uses no relative ones)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import"
            names.append(node.module)
            names += [f"{node.module}.{a.name}" for a in node.names]
    return names


def files(layer):
    p = ROOT / layer
    return [p] if p.suffix == ".py" else sorted(p.rglob("*.py"))


def _hits(name, banned):
    return name == banned or name.startswith(banned + ".")


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_only_downwards(layer):
    found = files(layer)
    assert found, f"no files in layer {layer}"
    bad = [f"{f.relative_to(ROOT.parent)} imports {n}" for f in found for n in imports(f)
           for banned in FORBIDDEN[layer] if _hits(n, banned)]
    assert not bad, "\n".join(bad)


def test_only_the_parallel_layer_imports_mpi4py():
    bad = [f"{f.relative_to(ROOT.parent)}" for f in ROOT.rglob("*.py")
           if f.relative_to(ROOT).parts[0] != MPI_HOME and any(_hits(n, "mpi4py") for n in imports(f))]
    assert not bad, "mpi4py imported outside pardem/parallel: " + ", ".join(bad)


def test_the_rules_catch_a_violation(tmp_path):
    """The checker itself sees an import inside a function body (not only at the top)."""
    f = tmp_path / "k.py"
    f.write_text("def g():\n    from mpi4py import MPI\n    import h5py.h5f\n")
    names = imports(f)
    assert any(_hits(n, "mpi4py") for n in names) and any(_hits(n, "h5py") for n in names)
