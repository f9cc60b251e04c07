"""Bad input is refused before any work: one line naming the field and the allowed values, exit 2."""
import json
import subprocess
import sys

import pytest

from pardem.config import DeckError, defaults
from pardem.io.deck_file import load_deck

from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.drivers import compress

BAD = [
    (["--set", "domain.radius=0"], "domain.radius", "(0.0, inf)"),
    (["--set", "domain.radius=-1e-3"], "domain.radius", "(0.0, inf)"),
    (["--set", "domain.density=0"], "domain.density", "(0.0, inf)"),
    (["--set", "bonds.young=-5"], "bonds.young", "(0.0, inf)"),
    (["--set", "bonds.young=[1e8, 0, 1e6]"], "bonds.young[1]", "(0.0, inf)"),
    (["--set", "bonds.young=[1e8, 1e6]"], "bonds.young", "list of 3"),
    (["--set", "bonds.poisson=0.5"], "bonds.poisson", "(-1.0, 0.5)"),
    (["--set", "bonds.poisson=-1"], "bonds.poisson", "(-1.0, 0.5)"),
    (["--set", "bonds.damping=1.5"], "bonds.damping", "[0.0, 1.0]"),
    (["--set", "bonds.damping=-0.1"], "bonds.damping", "[0.0, 1.0]"),
    (["--set", "bonds.law=elliptic"], "bonds.law", "'TOR', 'hankinson', 'linear', 'spherical', 'spherical_normalised'"),
    (["--set", "loading.strain=0"], "loading.strain", "[1e-12, 0.5)"),
    (["--set", "loading.strain=0.6"], "loading.strain", "[1e-12, 0.5)"),
    (["--set", "loading.axis=w"], "loading.axis", "'x', 'y', 'z'"),
    (["--set", "domain.radius=\"big\""], "domain.radius", "a number"),
    (["--set", "domain.box=0.01"], "domain.box", "list of 3"),
    (["--set", "bonds.yuong=1e8"], "bonds.yuong", "allowed keys in [bonds] are young, law"),
    (["--set", "solver.kind=1"], "[solver]", "allowed sections are domain"),
    (["--set", "run.dt=1.0"], "run.dt", "above the critical time step"),
    (["--set", "run.dt=-1.0"], "run.dt", "\"auto\""),
    (["--set", "output.series_every=1.5"], "output.series_every", "an integer"),
    (["--set", "noequals"], "noequals", "section.key=value"),
    (["--steps", "0"], "--steps", "from 1 to"),
    (["--set", "domain.box=[0.01, 0.01, 0.0003]"], "domain.box", "smaller than one element diameter"),
    (["--set", "domain.box=[0.01, 0.01, 0.0015]", "--set", "loading.axis=z"], "domain.box",
     "at least 2 element layers"),
    (["--config", "/"], "--config /", "cannot be read"),
    (["--set", "plates.friction=-0.1"], "plates.friction", "[0.0, inf)"),
    (["--set", "plates.law=rubber"], "plates.law", "'linear', 'hertz'"),
    (["--set", "plates.restitution=0"], "plates.restitution", "(0.0, 1.0]"),
    (["--set", "plates.lateral_walls=1"], "plates.lateral_walls", "true or false"),
    (["--set", "plates.poisson=0.6"], "plates.poisson", "(-1.0, 0.5)"),
]


@pytest.mark.parametrize("argv, field, allowed", BAD, ids=[b[1] + ":" + b[0][-1] for b in BAD])
def test_bad_input_exits_2_with_one_line(argv, field, allowed, capsys, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        compress.main(argv + ["--out", str(out), "--quiet"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert field in err[0] and allowed in err[0], err[0]
    assert not out.exists(), "no work may start on bad input"


def test_bad_config_file_subprocess_no_traceback(tmp_path):
    deck = tmp_path / "bad.toml"
    deck.write_text("[bonds]\npoisson = 0.7\n")
    p = subprocess.run([sys.executable, "-m", "pardem.drivers.compress", "--config", str(deck),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "Traceback" not in p.stderr
    assert "bonds.poisson = 0.7" in p.stderr and "(-1.0, 0.5)" in p.stderr


def test_missing_and_invalid_toml(tmp_path):
    with pytest.raises(DeckError, match="no such file"):
        load_deck(COMPRESS_SCHEMA, tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[bonds\n")
    with pytest.raises(DeckError, match="not valid TOML"):
        load_deck(COMPRESS_SCHEMA, bad)


def test_overrides_apply_after_file_and_parse_as_toml(tmp_path):
    deck = tmp_path / "d.toml"
    deck.write_text('[bonds]\nlaw = "linear"\nyoung = 5e6\n')
    d = load_deck(COMPRESS_SCHEMA, deck, ["bonds.young=[3e6, 2e6, 1e6]", "bonds.law=hankinson"])
    assert d["bonds"]["young"] == (3e6, 2e6, 1e6)
    assert d["bonds"]["law"] == "hankinson"
    assert d["domain"]["radius"] == COMPRESS_SCHEMA["domain"]["radius"].default


def test_default_deck_file_matches_builtin_defaults():
    """drivers/compress_default.toml documents the built-in default case: they must not drift."""
    import pathlib
    import tomllib
    path = pathlib.Path(__file__).parents[1] / "drivers" / "compress_default.toml"
    from pardem.config import check_deck
    raw = tomllib.loads(path.read_text())
    missing = [f"{s}.{k}" for s, fields in COMPRESS_SCHEMA.items() for k in fields if k not in raw.get(s, {})]
    assert not missing, f"drivers/compress_default.toml should document every key: {missing}"
    from_file = check_deck(COMPRESS_SCHEMA, raw)
    assert from_file == check_deck(COMPRESS_SCHEMA, {})
    assert set(defaults(COMPRESS_SCHEMA)) == set(from_file)


def test_help_lists_every_key(capsys):
    with pytest.raises(SystemExit) as exc:
        compress.main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for section, fields in COMPRESS_SCHEMA.items():
        for key in fields:
            assert key in text, key


def test_a_run_too_short_to_measure_says_so_and_exits_5(capsys, tmp_path):
    """50 steps end inside the plate's ramp: no sample to fit the modulus. The driver writes its
    files, prints one line saying why there is no modulus, and exits 5 (not 0 with E = nan)."""
    from pardem.drivers.cli import EXIT_NOT_MEASURED
    out = tmp_path / "short"
    try:
        code = compress.main(["--steps", "50", "--out", str(out), "--quiet"])
    except SystemExit as exc:
        code = exc.code
    assert code == EXIT_NOT_MEASURED == 5
    err = capsys.readouterr().err.strip().splitlines()
    short = [line for line in err if "too short to measure" in line]   # (after the dynamic-loading warning)
    assert len(short) == 1 and "ramp" in short[0] and "Traceback" not in "".join(err), err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["young_modulus"] is None and summary["samples_after_ramp"] == 0


def test_help_lists_the_allowed_values_of_every_choice_key():
    """Every key whose checker is a choice shows its options in --help (from the checker itself,
    so a new option appears without editing the help text)."""
    from pardem.config import describe
    text = describe(COMPRESS_SCHEMA)
    for section, fields in COMPRESS_SCHEMA.items():
        for key, f in fields.items():
            options = getattr(f.check, "options", None)
            if options:
                assert "(one of: " + ", ".join(map(str, options)) + ")" in text
    assert "(one of: TOR, hankinson, linear, spherical, spherical_normalised)" in text
