"""The HDF5 series (against the CSV series; its row buffer: what a crash, a restart and an unclosed
writer keep) and the force-strain plot of a compress run."""
import json
import struct
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from pardem.drivers import plot
from pardem.io.series import SERIES_COLUMNS, SERIES_UNITS, SeriesCSV, read_series
from pardem.io.series_h5 import SeriesH5, read_series_h5


def synthetic_samples(n, seed=0, step0=0):
    """``Reducer.sample``-like dicts with awkward floats (no round numbers, tiny and huge values)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        H = rng.normal(scale=10.0 ** rng.integers(-12, 0), size=(3, 3))
        out.append({"time": (step0 + k) * 1.2345678901234567e-7, "step": step0 + 7 * k,
                    "plate_displacement": np.float64(rng.uniform() * 1e-5),
                    "force_fixed": float(rng.normal() * 1e3), "force_moving": float(rng.normal() * 1e-9),
                    "H": H, "eps": 0.5 * (H + H.T), "bonds_broken": int(rng.integers(0, 10**9)),
                    "bonds_broken_step": int(rng.integers(0, 100)), "bonds_yielded": int(rng.integers(0, 10**6))})
    return out


@pytest.mark.parametrize("n_rows, flush_rows", [(37, 100), (37, 1), (250, 100), (250, 7)])
def test_round_trip_matches_csv(tmp_path, n_rows, flush_rows):
    """Every value of every column equals the CSV's (bit for bit), whatever the buffer size (rows
    left in the buffer at close, several writes of full buffers); dtypes, units and attributes."""
    samples = synthetic_samples(n_rows)
    csv, h5 = SeriesCSV(tmp_path / "series.csv"), SeriesH5(tmp_path / "series.h5", flush_rows=flush_rows)
    for s in samples:
        csv.append(s)
        h5.append(s)
    csv.close()
    h5.close()
    h5.close()   # idempotent
    c, h = read_series(tmp_path / "series.csv"), read_series_h5(tmp_path / "series.h5")
    assert list(h) == list(c) == list(SERIES_COLUMNS)
    for k in SERIES_COLUMNS:
        assert len(h[k]) == len(samples)
        np.testing.assert_array_equal(h[k], np.array(c[k]), err_msg=k)
    assert h["step"].dtype == np.int64 and h["time"].dtype == np.float64
    np.testing.assert_array_equal(h["eps_xy"], [s["eps"][0, 1] for s in samples])
    # plain h5py sees the same layout
    with h5py.File(tmp_path / "series.h5", "r") as f:
        assert list(f.attrs["columns"]) == list(SERIES_COLUMNS)
        assert "plate" in f.attrs["description"]
        assert sorted(f.keys()) == sorted(SERIES_COLUMNS)
        for name, unit in zip(SERIES_COLUMNS, SERIES_UNITS):
            ds = f[name]
            assert ds.ndim == 1 and ds.maxshape == (None,) and ds.shape == (len(samples),)
            assert ds.attrs["units"] == unit
            assert ds.dtype == (np.int64 if name == "step" or name.startswith("bonds_") else np.float64)


def test_empty_file_and_context_manager(tmp_path):
    with SeriesH5(tmp_path / "series.h5"):
        pass
    h = read_series_h5(tmp_path / "series.h5")
    assert list(h) == list(SERIES_COLUMNS) and all(len(v) == 0 for v in h.values())


@pytest.mark.parametrize("flush_rows", [1, 4, 100])
def test_resume_from_samples(tmp_path, flush_rows):
    """``samples=`` writes the kept rows first; appends continue after them; an old file is replaced
    (also when the old file's writer was buffering and the new one flushes part-way)."""
    first, later = synthetic_samples(10, seed=1), synthetic_samples(5, seed=2, step0=70)
    path = tmp_path / "series.h5"
    with SeriesH5(path, flush_rows=flush_rows) as h5:   # the interrupted run wrote more rows than kept
        for s in first + synthetic_samples(3, seed=3, step0=1000):
            h5.append(s)
    with SeriesH5(path, samples=first, flush_rows=flush_rows) as h5:
        assert h5.n_rows == len(first)
        assert len(read_series_h5(path)["step"]) == len(first)   # flushed before any append
        for s in later:
            h5.append(s)
    with SeriesH5(tmp_path / "straight.h5") as h5:
        for s in first + later:
            h5.append(s)
    resumed, straight = read_series_h5(path), read_series_h5(tmp_path / "straight.h5")
    for k in SERIES_COLUMNS:
        np.testing.assert_array_equal(resumed[k], straight[k], err_msg=k)
    assert list(resumed["step"]) == [s["step"] for s in first + later]


def _writer_script(path, options, n, end):
    return textwrap.dedent(f"""
        import os
        import numpy as np
        from pardem.io.series_h5 import SeriesH5
        w = SeriesH5({str(path)!r}, {options})
        for k in range({n}):
            H = np.full((3, 3), 1e-4 * k)
            w.append({{"time": 0.5 * k, "step": k, "plate_displacement": 1e-6 * k, "force_fixed": 2.0 * k,
                       "force_moving": 3.0 * k, "H": H, "eps": H, "bonds_broken": k,
                       "bonds_broken_step": 1, "bonds_yielded": 0}})
        {end}
    """)


@pytest.mark.parametrize("options, n, kept", [("flush_rows=3", 7, 6), ("flush_rows=3", 6, 6),
                                              ("flush_rows=100", 7, 0), ("flush_seconds=0.0", 4, 4)])
def test_a_crash_loses_only_the_unflushed_rows(tmp_path, options, n, kept):
    """A writer killed without close (``os._exit``: no atexit, no destructor) leaves the rows of its
    last flush readable, a prefix of those appended: the full buffers of ``flush_rows`` rows, or
    every row with ``flush_seconds = 0`` (then nothing is ever held back)."""
    path = tmp_path / "series.h5"
    r = subprocess.run([sys.executable, "-c", _writer_script(path, options, n, "os._exit(9)")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 9, r.stderr
    h = read_series_h5(path)
    assert list(h["step"]) == list(range(kept))
    np.testing.assert_array_equal(h["force_moving"], 3.0 * np.arange(kept))


def test_rows_reach_the_file_without_close(tmp_path):
    """Never closed: the buffered rows are written when the writer is garbage-collected and when the
    interpreter exits normally."""
    path = tmp_path / "exit.h5"
    r = subprocess.run([sys.executable, "-c", _writer_script(path, "flush_rows=100", 5, "")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert list(read_series_h5(path)["step"]) == [0, 1, 2, 3, 4]
    import gc
    w = SeriesH5(tmp_path / "gc.h5")
    samples = synthetic_samples(3)
    for s in samples:
        w.append(s)
    del w
    gc.collect()
    assert list(read_series_h5(tmp_path / "gc.h5")["step"]) == [s["step"] for s in samples]


class _Clock:
    def __init__(self):
        self.now = 1000.0

    def monotonic(self):
        return self.now


def test_flush_after_flush_seconds(tmp_path, monkeypatch):
    """With a large buffer, a row arriving ``flush_seconds`` after the last flush writes the buffer
    (a slow run loses at most that long of rows); ``flush()`` writes it at once. The written rows
    are those the datasets hold (their length), buffered ones are counted in ``n_rows``."""
    from pardem.io import series_h5
    clock = _Clock()
    monkeypatch.setattr(series_h5, "time", clock)
    samples = synthetic_samples(6)
    w = SeriesH5(tmp_path / "s.h5", flush_rows=1000, flush_seconds=5.0)
    written = lambda: w._f["step"].shape[0]
    for k, t in enumerate((1.0, 2.0, 4.9)):
        clock.now = 1000.0 + t
        w.append(samples[k])
    assert written() == 0 and w.n_rows == 3
    clock.now = 1005.0          # 5 s after the file was opened (its last flush)
    w.append(samples[3])
    assert written() == 4
    clock.now = 1009.0          # 4 s after that flush: buffered
    w.append(samples[4])
    assert written() == 4 and w.n_rows == 5
    w.flush()
    assert written() == 5
    w.append(samples[5])
    w.close()
    assert list(read_series_h5(tmp_path / "s.h5")["step"]) == [s["step"] for s in samples]


def test_buffered_rows_keep_the_values_appended(tmp_path):
    """A row held in the buffer holds copies: changing the caller's arrays afterwards (a sampler
    reusing its arrays) does not change what is written."""
    from pardem.io.series import dict_row
    cols = ("step", "pressure")
    value = np.array(1.5)
    w = SeriesH5(tmp_path / "s.h5", columns=cols, units=("1", "Pa"), row=dict_row(cols),
                 int_columns={"step"})
    w.append({"step": 0, "pressure": value})
    value[()] = -7.0
    w.append({"step": 1, "pressure": value})
    w.close()
    np.testing.assert_array_equal(read_series_h5(tmp_path / "s.h5")["pressure"], [1.5, -7.0])


@pytest.mark.parametrize("option, message", [({"flush_rows": 0}, "flush_rows must be an integer >= 1"),
                                             ({"flush_rows": 2.5}, "flush_rows must be an integer >= 1"),
                                             ({"flush_seconds": -1.0}, "flush_seconds must be a finite"),
                                             ({"flush_seconds": float("nan")}, "flush_seconds must be a finite")])
def test_bad_buffer_options(tmp_path, option, message):
    with pytest.raises(ValueError, match=message):
        SeriesH5(tmp_path / "s.h5", **option)


def png_size(path):
    """(width, height) from the PNG signature and IHDR chunk; fails on anything else."""
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    assert head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from pardem.drivers import compress
    out = tmp_path_factory.mktemp("compress") / "run"
    assert compress.main(["--out", str(out), "--quiet", "--set", "domain.box=[0.003,0.003,0.003]",
                          "--set", "domain.radius=0.25e-3"]) == 0
    return out


def test_plot_of_a_compress_run(run_dir, capsys):
    pytest.importorskip("matplotlib")
    assert plot.main([str(run_dir)]) == 0
    png = run_dir / "force_strain.png"
    w, h = png_size(png)
    assert w >= 800 and h >= 300 and w > h            # two panels side by side
    assert png.stat().st_size > 20_000                # curves, labels and legend, not a blank canvas
    assert str(png) in capsys.readouterr().out


def test_plot_from_h5_only_and_out_option(run_dir, tmp_path):
    """Without series.csv the plot reads series.h5; --out picks the file."""
    pytest.importorskip("matplotlib")
    d = tmp_path / "h5run"
    d.mkdir()
    (d / "summary.json").write_text((run_dir / "summary.json").read_text())
    csv = read_series(run_dir / "series.csv")
    eps_cols = ("eps_xx", "eps_yy", "eps_zz", "eps_xy", "eps_xz", "eps_yz")
    samples = []
    for k in range(len(csv["step"])):
        xx, yy, zz, xy, xz, yz = (csv[c][k] for c in eps_cols)
        eps = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        samples.append({"step": int(csv["step"][k]), "time": csv["time"][k], "eps": eps, "H": eps,
                        **{c: csv[c][k] for c in ("plate_displacement", "force_fixed", "force_moving")},
                        **{c: int(csv[c][k]) for c in ("bonds_broken", "bonds_broken_step", "bonds_yielded")}})
    SeriesH5(d / "series.h5", samples=samples).close()
    out = tmp_path / "other.png"
    assert plot.main([str(d), "--out", str(out)]) == 0
    assert png_size(out)[0] >= 800
    assert not (d / "force_strain.png").exists()


@pytest.mark.parametrize("case", ["no_dir", "no_summary", "no_series", "bad_json", "empty_series"])
def test_plot_bad_dir_is_one_line_exit_2(tmp_path, capsys, case):
    d = tmp_path / "run"
    if case != "no_dir":
        d.mkdir()
    if case in ("no_series", "empty_series"):
        (d / "summary.json").write_text(json.dumps({"cross_section": 1e-5, "loading_axis": "x"}))
    if case == "no_summary":
        SeriesCSV(d / "series.csv").close()
    if case == "bad_json":
        (d / "summary.json").write_text("{not json")
    if case == "empty_series":
        SeriesCSV(d / "series.csv").close()
    with pytest.raises(SystemExit) as exc:
        plot.main([str(d)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("pardem: error: ") and err.count("\n") == 1, err


def test_plot_without_matplotlib(run_dir, tmp_path, capsys, monkeypatch):
    """matplotlib missing: the one documented line and exit 2, nothing written."""
    for name in list(sys.modules):
        if name == "matplotlib" or name.startswith("matplotlib."):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)     # makes ``import matplotlib`` fail
    out = tmp_path / "x.png"
    with pytest.raises(SystemExit) as exc:
        plot.main([str(run_dir), "--out", str(out)])
    assert exc.value.code == 2
    assert capsys.readouterr().err == \
        "pardem: error: matplotlib is not installed: pip install 'pardem[plot]'\n"
    assert not out.exists()


def test_plot_help(capsys):
    with pytest.raises(SystemExit) as exc:
        plot.main(["--help"])
    assert exc.value.code == 0
    assert "DIR" in capsys.readouterr().out


def test_other_columns_round_trip(tmp_path):
    """A driver's own columns (dict rows, its units and int columns): CSV and HDF5 agree bit for
    bit, the units and the column order are the given ones, and compress's defaults are unchanged."""
    from pardem.io.series import dict_row
    cols, units = ("step", "pressure", "count"), ("1", "Pa", "1")
    rng = np.random.default_rng(4)
    rows = [{"step": 3 * k, "pressure": float(rng.normal() * 10.0 ** rng.integers(-9, 9)),
             "count": int(rng.integers(0, 10**6))} for k in range(29)]
    csv = SeriesCSV(tmp_path / "s.csv", cols, dict_row(cols))
    h5 = SeriesH5(tmp_path / "s.h5", rows[:5], cols, units, dict_row(cols), "test series",
                  int_columns={"step", "count"})
    for r in rows:
        csv.append(r)
    for r in rows[5:]:
        h5.append(r)
    csv.close()
    h5.close()
    a, b = read_series(tmp_path / "s.csv", None), read_series_h5(tmp_path / "s.h5")
    assert list(a) == list(b) == list(cols)
    for k in cols:
        np.testing.assert_array_equal(np.asarray(a[k]), b[k].astype(float))
    with h5py.File(tmp_path / "s.h5") as f:
        assert [f[k].attrs["units"] for k in cols] == list(units)
        assert f["count"].dtype == np.int64 and f["pressure"].dtype == np.float64
        assert f.attrs["description"] == "test series"
    assert SeriesCSV.__init__.__defaults__[0] == SERIES_COLUMNS


def test_csv_header_carries_the_units(tmp_path):
    """The CSV header names each column with the HDF5 series' unit (dimensionless columns bare),
    and the readers key the columns by bare name."""
    import csv as csv_module
    from pardem.io.series import dict_row, read_series_rows
    csv = SeriesCSV(tmp_path / "series.csv")
    for s in synthetic_samples(3):
        csv.append(s)
    csv.close()
    with open(tmp_path / "series.csv", newline="") as fh:
        head = next(csv_module.reader(fh))
    assert head == ["step", "time [s]", "plate_displacement [m]", "force_fixed [N]", "force_moving [N]",
                    "eps_xx", "eps_yy", "eps_zz", "eps_xy", "eps_xz", "eps_yz",
                    "bonds_broken", "bonds_broken_step", "bonds_yielded"]
    assert [u for u in SERIES_UNITS if u != "1"] == ["s", "m", "N", "N"]
    assert list(read_series(tmp_path / "series.csv", None)) == list(SERIES_COLUMNS)
    cols, units = ("step", "stress_xx", "count"), ("1", "Pa", "1")
    own = SeriesCSV(tmp_path / "own.csv", cols, dict_row(cols), units=units)
    own.append({"step": 2, "stress_xx": 1.5, "count": 7})
    own.close()
    assert (tmp_path / "own.csv").read_text().splitlines() == ["step,stress_xx [Pa],count", "2,1.5,7"]
    assert read_series_rows(tmp_path / "own.csv") == [{"step": "2", "stress_xx": "1.5", "count": "7"}]
    with pytest.raises(ValueError, match="3 columns but 2 units"):
        SeriesCSV(tmp_path / "bad.csv", cols, dict_row(cols), units=("1", "Pa"))
