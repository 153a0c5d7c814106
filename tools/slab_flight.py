"""What a flight cut into slabs, one per core, could gain (docs/scaling.md, 2.6).

The scheme it measures: each core runs the events of its own slab of the
domain; an event that reads or writes particles within one cell width of
a cut (a *boundary event*: its particle or its partner that near a cut)
waits until every slab has processed all its events before it, and runs
alone. Between two boundary events the slabs run side by side, so the
flight's critical path, in events, is the sum over those stretches of the
largest slab's count, plus one per boundary event. Each boundary event
also costs a synchronisation, given here in units of one event's time.

Input: the dump of a probe build (tools/probes/slab_events.patch applied
to a scratch copy of the source; run with PROBE_EVENTS=FILE). Per flight
it holds the cell widths, every particle's (x, y) at the flight's start,
and every event's (x, y) of its particle and its partner.

    python3 tools/slab_flight.py FILE [FILE...]

Two rules place the cuts: at quantiles of the particles' positions at the
flight's start, or at quantiles of the positions of the previous flight's
events (what a run could use, to share the events). Needs numpy.
"""

import sys

import numpy as np

# Synchronisation costs tried, in events: 130 ns (a flag round trip
# between the two vCPUs of the development host) is about half of a riser
# event (0.27 us) and a jet-bed event; 2 events is a pessimistic bound.
BARRIER_EVENTS = (0.5, 2.0)


def flights(path):
    """Yields (cell widths (2,), particles (n, 2), events (m, 4)) per flight."""
    a = np.fromfile(path, dtype="<f8")
    starts = np.flatnonzero(a == np.inf)
    for k, s in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else len(a)
        widths = a[s + 1 : s + 3]
        mark = s + 3 + np.flatnonzero(a[s + 3 : end] == -np.inf)[0]
        particles = a[s + 3 : mark].reshape(-1, 2)
        events = a[mark + 2 : end].reshape(-1, 4)
        yield widths, particles, events


def critical_path(events, cuts, width, axis):
    """(critical path in events, boundary events) of one flight."""
    own, partner = events[:, axis], events[:, 2 + axis]
    near = np.zeros(len(events), bool)
    for c in cuts:
        near |= np.abs(own - c) < width
        near |= np.abs(partner - c) < width  # NaN (no partner): False
    slab = np.searchsorted(np.asarray(cuts), own, side="right")
    path, start = 0, 0
    boundary = np.flatnonzero(near)
    for b in list(boundary) + [len(events)]:
        if b > start:
            path += np.bincount(slab[start:b], minlength=len(cuts) + 1).max()
        start = b + 1
    return path + len(boundary), len(boundary)


def slab_statistics(path):
    """Totals per (axis, slabs, rule): [events, critical path, boundary, flights]."""
    totals = {}
    previous = None
    for widths, particles, events in flights(path):
        for axis in (0, 1):
            for slabs in (2, 4):
                q = [(k + 1) / slabs for k in range(slabs - 1)]
                at_start = list(np.quantile(particles[:, axis], q))
                rules = {
                    "particles": at_start,
                    "previous events": (
                        list(np.quantile(previous[:, axis], q))
                        if previous is not None and len(previous)
                        else at_start
                    ),
                }
                for rule, cuts in rules.items():
                    c, nb = critical_path(events, cuts, widths[axis], axis)
                    t = totals.setdefault((axis, slabs, rule), [0, 0, 0, 0])
                    t[0] += len(events)
                    t[1] += c
                    t[2] += nb
                    t[3] += 1
        previous = events
    return totals


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        print(f"\n{path}\n")
        print(
            "| cut normal to | slabs | cuts at the quantiles of | events a flight "
            "| boundary events a flight | speed-up, free sync "
            + "".join(f"| sync = {b} events " for b in BARRIER_EVENTS)
            + "|"
        )
        print("|---" * (6 + len(BARRIER_EVENTS)) + "|")
        for (axis, slabs, rule), (n, c, nb, f) in sorted(slab_statistics(path).items()):
            row = f"| {'xy'[axis]} | {slabs} | {rule} | {n / f:.0f} | {nb / f:.1f} | {n / c:.2f} "
            row += "".join(f"| {n / (c + b * nb):.2f} " for b in BARRIER_EVENTS)
            print(row + "|")


if __name__ == "__main__":
    main()
