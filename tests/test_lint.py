"""The code passes the project's linter: ruff with the configuration of ``pyproject.toml``
(pyflakes' findings and closures that capture a loop variable), over the package, the tests, the
benchmarks and the examples. ruff is a test dependency (``pip install -e .[test]``, ``setup.sh``)."""
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUFF = os.path.join(os.path.dirname(sys.executable), "ruff")


def ruff(*args, cwd=ROOT):
    assert os.path.exists(RUFF), f"{RUFF} missing: ruff is a test dependency (bash setup.sh installs it)"
    return subprocess.run([RUFF, "check", "--output-format", "concise", "--no-cache", *args],
                          cwd=cwd, capture_output=True, text=True)


def test_the_code_has_no_lint_findings():
    r = ruff("pardem", "tests", "benchmarks", "examples")
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_configuration_catches_an_unused_import_and_a_late_bound_closure(tmp_path):
    """The same configuration on a file with the two kinds of finding it selects: both reported."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f():\n    fs = []\n    for k in range(3):\n"
                   "        fs.append(lambda: k)\n    return fs\n")
    r = ruff("--config", os.path.join(ROOT, "pyproject.toml"), str(bad), cwd=tmp_path)
    assert r.returncode == 1
    assert "F401" in r.stdout and "B023" in r.stdout, r.stdout
