"""How long a device takes, at least, to answer each command: the age a step checks.

The host notes when it sends each command (:meth:`EchoTimes.sent`) and when it starts each
read of the link (:meth:`EchoTimes.reading`); a read takes everything the link holds when it
starts. So a state that echoes command ``S`` for the first time had not arrived when the read
before started: ``S`` waited at least (that start - its send) for its answer. A command still
unanswered when the latest read started has waited at least (that start - its send).

Both are lower bounds that time the host itself was stalled (a garbage collection, the
scheduler, a slow controller between steps) never inflates: a stall only moves the reads
later, and a read after the stall finds the answer waiting. A link that delays the device's
frames by 0.2 s shows as 0.2 s, whatever the host did meanwhile.
"""

from __future__ import annotations

from collections import OrderedDict

#: Commands remembered to recognise their echoes (several seconds of commands at 500 Hz).
KEPT = 4096


class EchoTimes:
    """The send times of commands and the starts of reads, for :meth:`age`."""

    def __init__(self) -> None:
        self._known: OrderedDict[int, int] = OrderedDict()  # seq -> send ns, newest last
        self._pending: OrderedDict[int, int] = OrderedDict()  # not answered yet, oldest first
        self._previous_read = 0
        self._read = 0
        self._answered_after = 0  # ns the latest answered command waited, at least

    def sent(self, seq: int, ns: int) -> None:
        """Note command ``seq`` sent at host time ``ns`` (``perf_counter_ns``)."""
        self._known.pop(seq, None)  # a wrapped number: its old send is forgotten
        self._pending.pop(seq, None)
        self._known[seq] = self._pending[seq] = ns
        for table in (self._known, self._pending):
            if len(table) > KEPT:
                table.popitem(last=False)

    def reading(self, ns: int) -> None:
        """Note that a read of everything the link holds starts at ``ns``."""
        self._previous_read, self._read = self._read, ns

    def ours(self, seq: int) -> bool:
        """Whether ``seq`` is a command this host sent (among the last :data:`KEPT`)."""
        return seq in self._known

    def echoed(self, seq: int) -> None:
        """Note a state of the latest read that echoes command ``seq``.

        The device holds its newest command, so an echo of ``seq`` answers every command sent
        before it too (those it never held were overtaken).
        """
        if seq not in self._pending:
            return  # answered already, or not ours
        self._answered_after = max(0, self._previous_read - self._pending[seq])
        while self._pending:
            if self._pending.popitem(last=False)[0] == seq:
                break

    def forget_pending(self) -> None:
        """Drop the unanswered commands (the stops of an episode that ended)."""
        self._pending.clear()
        self._answered_after = 0

    def clear(self) -> None:
        """Forget everything (the link closed)."""
        self._known.clear()
        self.forget_pending()

    def age(self) -> float:
        """Longest time, s, the device has taken at least to answer a recent command."""
        waited = self._answered_after
        if self._pending:
            waited = max(waited, self._read - next(iter(self._pending.values())))
        return waited * 1e-9


__all__ = ["KEPT", "EchoTimes"]
