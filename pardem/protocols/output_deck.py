"""The deck sections every protocol shares, defined once: ``[checkpoint]`` (when and how the runner
writes checkpoints, ``pardem.io.checkpoint_writer.DECK_SECTION``) and ``[output]`` (ParaView
snapshots, the series' sampling, the figures), which ``output_section`` assembles for a protocol's
schema from the shared fields plus the protocol's own keys. The output folder itself is the
command line's ``--out`` (``pardem.drivers.cli``).

The runner reads ``output.vtk_every`` (its ParaView writer) of every protocol of one simulation;
the protocols read the rest.
"""
from pardem.config import Field, boolean, number, optional
from pardem.io.checkpoint_writer import DECK_SECTION

CHECKPOINT_SECTION = DECK_SECTION
PARAVIEW_FILES = "DIR/paraview/pardem.pvd"


def vtk_every(files=PARAVIEW_FILES, when="", of=""):
    """``output.vtk_every``: steps between ParaView snapshots (``of`` what) written to ``files``
    (``when`` prefixes the description, e.g. the option it applies to)."""
    return Field(0, number(lo=0, lo_open=False, integer=True),
                 f"{when}steps between ParaView snapshots{f' of {of}' if of else ''} ({files}); 0 = none")


def series_every(doc="steps between series samples; 0 = about 200 samples per run", zero=None):
    """``output.series_every``: steps between the samples of a series, 0 = about 200 per run (the
    protocol's default). ``zero``: the deck's value for 0 (None: "not set"; or 0 itself)."""
    check = number(lo=0, lo_open=False, integer=True)
    return Field(0, optional(number(lo=0, integer=True)) if zero is None else check, doc)


def samples(doc):
    """``output.samples``: rows of a loading series (per its ``doc``)."""
    return Field(200, number(lo=2, lo_open=False, integer=True), doc)


def plot(figures):
    """``output.plot``: draw ``figures`` (a text naming them) at the end."""
    return Field(True, boolean, f"draw {figures} (needs matplotlib)")


def output_section(series_every=None, samples=None, vtk=None, plot_figures=None, before=None, after=None):
    """A protocol's ``[output]`` section, in the order: its own keys ``before``, the series'
    sampling (the Field ``series_every`` or ``samples``, made by the functions of those names),
    ``vtk_every`` (``vtk``, default ``vtk_every()``), its own keys ``after``, ``plot`` (when
    ``plot_figures`` names the figures)."""
    section = dict(before or {})
    if series_every is not None:
        section["series_every"] = series_every
    if samples is not None:
        section["samples"] = samples
    section["vtk_every"] = vtk if vtk is not None else vtk_every()
    section.update(after or {})
    if plot_figures is not None:
        section["plot"] = plot(plot_figures)
    return section
