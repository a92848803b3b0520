"""What a serial bridge records of a run: the samples' words as a block, and the link's
and the board's counters for the run's ``bridge`` metadata (a part of
:class:`labrig.bridge.serial.SerialBridge`)."""
from __future__ import annotations

import numpy as np

from labrig.bridge import protocol as P
from labrig.bridge.base import SampleBlock
from labrig.bridge.hbridge import encoder_record, words_block
from labrig.bridge.settings import is_board_loop

#: STATUS counters that add up over a session (a run's are differences)
_BOARD_CUMULATIVE = ("samples_sent", "rx_crc_errors", "rx_overruns", "watchdog_trips")


class RunRecord:
    """The run's record, from the state a :class:`~labrig.bridge.serial.SerialBridge`
    keeps (its settings, hello, marks, board status and errors, trip, index events)."""

    def _block(self, first: int, w: np.ndarray) -> SampleBlock:
        """A SAMPLES frame's words as a block: raw volts from the MS150 bridge; from an
        H-bridge board the output in volts of the supply and the encoder's signed count
        (the rig's ``pos`` unit is counts: ``sensors.encoder_counts_per_unit``)."""
        exp = self._exp
        blk = words_block(first, w, self.settings, exp is not None and exp.loop == "closed",
                          exp is not None and is_board_loop(exp, self.settings))
        if self.settings.firmware == "hbridge":   # the run's lowest and highest count
            lo, hi, r = int(blk.pos.min()), int(blk.pos.max()), self._count_range
            self._count_range = (lo, hi) if r is None else (min(r[0], lo), max(r[1], hi))
        return blk

    def counters(self) -> dict:
        """Link and board counters of the current run, for the run's ``bridge`` metadata.

        Every count is this run's own (since :meth:`configure`), so ``dropped_samples``
        equals the run's gap rows. Board counters are differences of the STATUS fetched
        before the run and at :meth:`stop`; they are left out when either STATUS was lost.
        """
        c = {"firmware": self.hello.get("firmware", "unknown"), "board": self.hello.get("board"),
             "port": self.port}
        if self.board_id:
            c["board_id"] = P.format_board_id(self.board_id)
        c.update({k: int(v - self._mark[k]) for k, v in self._totals().items()})
        st, base = self.board_status, self._board_mark
        if st:
            if base:
                for k in _BOARD_CUMULATIVE:
                    c[f"board_{k}"] = int(st[k] - base[k])
            c["board_sample_overruns"] = int(st["sample_overruns"])   # reset by START
        if self.board_errors[self._errors_mark:]:
            c["board_errors"] = self.board_errors[self._errors_mark:]
        if self.trip is not None:
            c["trip"] = dict(self.trip)
        if self.settings.firmware == "hbridge" and self._exp is not None:
            faults = (int(st["encoder_faults"] - base["encoder_faults"])
                      if st and base and "encoder_faults" in base else None)
            r = self._count_range
            c["encoder"] = encoder_record(self._index_events, faults,
                                          self._rig.bridge.index_counts, self._rig.bridge.decoding,
                                          r[1] - r[0] if r else 0)
        return c

