"""The import direction of ARCHITECTURE.md, read from the source (every import statement, also
inside functions): drivers -> protocols -> restart -> engine (+ io, parallel) -> physics.

Each rule is a list of packages a layer must not import. The test parses the files with ``ast``,
so an import hidden in a function body counts too; and no group of modules imports itself around
(an import cycle), even through imports hidden in functions.
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
    "engine": ["mpi4py", "h5py", "meshio", "pardem.protocols", "pardem.drivers", "pardem.restart"],
    "parallel": ["h5py", "meshio", "pardem.engine.simulation", "pardem.protocols", "pardem.drivers",
                 "pardem.io"],
    "io": ["mpi4py", "pardem.protocols", "pardem.drivers", "pardem.engine", "pardem.restart"],
    "restart.py": ["mpi4py", "h5py", "meshio", "pardem.protocols", "pardem.drivers"],
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


def modules():
    """Dotted module name -> file, for every module of pardem."""
    out = {}
    for f in ROOT.rglob("*.py"):
        parts = list(f.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def import_graph(mods):
    """Module -> the pardem modules it imports (``from a.b import c`` names module ``a.b.c`` when
    that is a module, else ``a.b``)."""
    def owner(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name
    graph = {}
    for m, f in mods.items():
        graph[m] = {t for t in (owner(n) for n in imports(f) if n and n.startswith("pardem")) if t and t != m}
    return graph


def cycles(graph):
    """The strongly connected groups of more than one module (Tarjan), each sorted."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle():
    found = cycles(import_graph(modules()))
    assert not found, "import cycles: " + "; ".join(" -> ".join(c) for c in found)


def test_the_cycle_check_finds_a_cycle_hidden_in_a_function():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


# calls that open, create, remove or list files (prefix = the module's usual import name)
FILE_CALLS = {"open", "io.open", "os.open", "os.fdopen", "os.remove", "os.unlink", "os.rename", "os.replace",
              "os.rmdir", "os.mkdir", "os.makedirs", "os.listdir", "os.scandir", "os.stat", "os.fsync",
              "os.path.exists", "os.path.isfile", "os.path.isdir", "shutil.rmtree", "shutil.copy",
              "shutil.copyfile", "shutil.move", "glob.glob", "tempfile.mkstemp", "tempfile.mkdtemp",
              "h5py.File", "np.save", "np.savez", "np.load", "np.savetxt", "np.loadtxt", "json.dump",
              "json.load", "tomllib.load", "meshio.write", "meshio.read"}
FILE_METHODS = {"write_text", "read_text", "write_bytes", "read_bytes", "savefig", "touch"}
# outside pardem/io: the drivers may create the folders of a run (nothing else)
FOLDER_CALLS = {"drivers": {"os.makedirs"}}


def _dotted(node):
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return f"{base}.{node.attr}" if base else None
    return None


def file_calls(path):
    """``(line, call)`` of every call in ``path`` that touches a file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Call):
            name = _dotted(node.func)
            if name in FILE_CALLS or (isinstance(node.func, ast.Attribute) and node.func.attr in FILE_METHODS):
                out.append((node.lineno, name or node.func.attr))
    return out


def test_only_the_io_layer_touches_files():
    bad = []
    for f in sorted(ROOT.rglob("*.py")):
        layer = f.relative_to(ROOT).parts[0]
        if layer == "io":
            continue
        allowed = FOLDER_CALLS.get(layer, set())
        bad += [f"{f.relative_to(ROOT.parent)}:{line} {name}" for line, name in file_calls(f) if name not in allowed]
    assert not bad, "file access outside pardem/io:\n" + "\n".join(bad)


def test_the_file_check_sees_opens_and_figures(tmp_path):
    f = tmp_path / "k.py"
    f.write_text("import os\ndef g(fig, p):\n    with open(p) as fh:\n        pass\n    fig.savefig(p)\n"
                 "    os.makedirs(p)\n")
    assert sorted(n for _, n in file_calls(f)) == ["fig.savefig", "open", "os.makedirs"]


# driver modules whose main runs no protocol (a figure of a finished run's files)
NOT_RUNS = {"plot"}
RUNNER_CALLS = {"run_protocol", "protocol_main"}     # protocol_main is run_protocol under cli.run_driver


def runs_through_the_runner(path):
    """None if ``path`` has no top-level ``main``; else whether ``main`` calls ``run_protocol`` (or
    ``protocol_main``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    mains = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main"]
    if not mains:
        return None
    return any(isinstance(n, ast.Call) and (_dotted(n.func) or "").rpartition(".")[2] in RUNNER_CALLS
               for n in ast.walk(mains[0]))


def test_every_driver_runs_through_the_runner():
    drivers = sorted((ROOT / "drivers").glob("*.py"))
    with_main = [f for f in drivers if runs_through_the_runner(f) is not None and f.stem not in NOT_RUNS]
    assert len(with_main) >= 8, [f.stem for f in with_main]
    bad = [f.stem for f in with_main if not runs_through_the_runner(f)]
    assert not bad, "drivers whose main bypasses drivers.runner.run_protocol: " + ", ".join(bad)


def test_the_runner_imports_no_protocol():
    bad = [n for n in imports(ROOT / "drivers" / "runner.py") if _hits(n, "pardem.protocols")]
    assert not bad, "pardem/drivers/runner.py imports " + ", ".join(bad)


def test_the_runner_check_sees_a_bypass(tmp_path):
    f = tmp_path / "d.py"
    f.write_text("def main(argv=None):\n    return run_driver(comm, run, args)\n")
    assert runs_through_the_runner(f) is False
    f.write_text("def main(argv=None):\n    return runner.protocol_main(D, parser, argv)\n")
    assert runs_through_the_runner(f) is True
    f.write_text("def other():\n    pass\n")
    assert runs_through_the_runner(f) is None
