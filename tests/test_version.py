"""One version everywhere: pardem.__version__, pyproject.toml, CITATION.cff and the CHANGELOG's
latest release agree (a release bumps them together)."""
import re
import tomllib
from pathlib import Path

import pardem

ROOT = Path(__file__).resolve().parents[1]


def test_version_is_the_pyproject_version():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert pardem.__version__ == project["version"]


def test_citation_and_changelog_name_the_same_version():
    cff = re.search(r"^version:\s*\"?([^\"\s]+)", (ROOT / "CITATION.cff").read_text(), re.M)
    releases = re.findall(r"^## \[(\d[^\]]*)\]", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert cff and cff.group(1) == pardem.__version__
    assert releases and releases[0] == pardem.__version__      # the newest release comes first
