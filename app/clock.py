"""The live loop's clock: one step per control period (dt / speed), without bursts, re-phased on a takeover."""

from __future__ import annotations


class RateClock:
    """When the next step is due.

    After a late step the clock catches up by at most one missed period, so a stall never turns into a burst
    of steps. When the operator starts holding the takeover key the step is taken at once and the clock
    re-phases from it, so a takeover does not wait up to a whole period; the rate itself never changes.
    """

    def __init__(self, now: float) -> None:
        self.next_at = now

    def restart(self, now: float) -> None:
        """After a pause: the next step is due now."""
        self.next_at = now

    def wait(self, now: float, onset: bool) -> float:
        """Seconds to wait before the next step (0: step now)."""
        return 0.0 if onset else max(0.0, self.next_at - now)

    def stepped(self, after: float, period: float, onset: bool) -> None:
        """A step has just been taken (it ended at ``after``)."""
        self.next_at = after + period if onset else max(self.next_at + period, after - period)
