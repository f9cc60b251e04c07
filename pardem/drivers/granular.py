"""``GranularDriver``: the part the granular drivers (isotropic, triaxial, biaxial, response) share
over ``pardem.drivers.runner``: the restart contract and the series of
``pardem.protocols.granular_output``."""
from pardem import restart
from pardem.drivers.runner import ProtocolDriver
from pardem.protocols import granular_output as gout


class GranularDriver(ProtocolDriver):
    """The granular drivers' common part: a checkpoint written by the same driver, the restart
    policy ``restart_may_change`` (keys besides [output] and [checkpoint]; ``restart_what`` words
    it for the message), ``pardem.engine.granular`` cases, the series ``<name>.csv``/``.h5`` of
    ``columns`` with ``units`` (rank 0; rows kept in the checkpoints), the protocol's ``run.state``."""
    restart_may_change = ()
    restart_what = ""
    columns = units = description = ()
    int_columns = ("step",)
    slab_axes = "xyz"

    def inspect(self, run):
        return gout.inspect_restart(run.args.restart, self.name, comm=run.comm)

    def read_deck(self, run):
        deck = super().read_deck(run)
        self.check(run, deck)
        if run.meta is not None:
            gout.check_restart(run.args.restart, run.meta, deck, self.schema, run.args.steps,
                               self.restart_may_change, self.restart_what)
        return deck

    def check(self, run, deck):
        """Protocol checks of the deck (DeckError) and command-line extras."""

    def restore(self, run):
        run.state = run.meta["protocol"]
        return restart.load_case(run.comm, run.args.restart, meta=run.meta,
                                 slab_axis=self.slab_axes.index(run.deck["run"]["slab_axis"]))

    def rows(self, run):
        """The series rows so far (from the checkpoint on restart)."""
        return gout.rows_of(run.meta["series"], self.columns, self.int_columns) if run.meta else []

    def open_series(self, run):
        run.series = gout.Series(run.comm, run.out, self.name, self.columns, self.units, self.description,
                                 self.rows(run), self.int_columns)
        run.files.callback(run.series.close)

    def payload(self, run):
        return gout.payload(run.case, run.deck, self.protocol_state(run), run.series.rows, self.columns)

    def protocol_state(self, run):
        return run.state
