"""What a flight cut into slabs, one per core, could gain (docs/scaling.md, 2.6).

The scheme it measures: each core runs the events of its own slab of the
domain, the slabs cut on cell faces. An event whose particle or partner
lies in a cell next to a cut (within one cell width of it, the faces
included, so that the crossings into those cells count) is a *boundary
event*: a prediction for such a particle reads the other slab's cells.
It waits until every slab has processed all its events before it, and
runs alone. Between two boundary events (a *window*) the slabs run side by
side, so the flight's critical path, in events, is the sum over the
windows of the largest slab's count, plus one per boundary event. Each
boundary event also costs a synchronisation, given in units of one
event's time.

That best case assumes each boundary event is known when the window
before it starts. One that was predicted later, by an event inside the
window (a *surprise*), may come after a slab has already passed its time;
a window-level optimistic scheme then undoes the window and runs it
again on one core. The second estimate charges every window that ends in
a surprise its events once more, serially (a pessimistic count).

Input: the dump of a probe build (tools/probes/slab_events.patch applied
to a scratch copy of the source; run it on one thread with
RAYON_NUM_THREADS=1 PROBE_EVENTS=FILE). Per flight it holds the cell
widths and the grid's lower corner, every particle's (x, y) at the
flight's start, and per event the
(x, y) of its particle and its partner, its time and the time it was
predicted at.

    python3 tools/slab_flight.py FILE [FILE...]

Two rules place the cuts, each rounded to the nearest cell face: at
quantiles of the particles' positions at the flight's start, or at
quantiles of the positions of the previous flight's events (what a run
could use, to share the events). Needs numpy.
"""

import sys

import numpy as np

# Synchronisation costs tried, in events: a flag's round trip between the
# two vCPUs of the development host took 110-540 ns, half a riser event
# (0.27 us) to two. The redone-windows column uses the first.
BARRIER_EVENTS = (0.5, 2.0)


def flights(path):
    """Yields (cell widths (2,), grid corner (2,), particles (n, 2),
    events (m, 6)) per flight."""
    a = np.fromfile(path, dtype="<f8")
    starts = np.flatnonzero(a == np.inf)
    for k, s in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else len(a)
        widths, corner = a[s + 1 : s + 3], a[s + 3 : s + 5]
        mark = s + 5 + np.flatnonzero(a[s + 5 : end] == -np.inf)[0]
        particles = a[s + 5 : mark].reshape(-1, 2)
        events = a[mark + 2 : end].reshape(-1, 6)
        yield widths, corner, particles, events


def critical_path(events, cuts, width, axis):
    """(best-case critical path, with surprise windows redone, boundary
    events, surprises) of one flight, in events."""
    own, partner = events[:, axis], events[:, 2 + axis]
    time, predicted_at = events[:, 4], events[:, 5]
    # On a cut's neighbour cells, their outer faces included (round-off).
    reach = width * (1.0 + 1e-9)
    near = np.zeros(len(events), bool)
    for c in cuts:
        near |= np.abs(own - c) <= reach
        near |= np.abs(partner - c) <= reach  # NaN (no partner): False
    slab = np.searchsorted(np.asarray(cuts), own, side="right")
    boundary = np.flatnonzero(near)
    # A window starts at the boundary event before it, the first at the
    # flight's start (when the first events were predicted).
    window_start = np.concatenate([[np.min(predicted_at)], time[boundary[:-1]]])
    surprise = predicted_at[boundary] > window_start
    best, redo, start = 0, 0, 0
    for k, b in enumerate(list(boundary) + [len(events)]):
        if b > start:
            best += np.bincount(slab[start:b], minlength=len(cuts) + 1).max()
            if k < len(boundary) and surprise[k]:
                redo += b - start
        start = b + 1
    best += len(boundary)
    return best, best + redo, len(boundary), int(surprise.sum())


def slab_statistics(path):
    """Totals per (axis, slabs, rule): [events, best-case path, path with
    redone windows, boundary events, surprises, flights]."""
    totals = {}
    previous = None
    for widths, corner, particles, events in flights(path):
        for axis in (0, 1):
            w, lo = widths[axis], corner[axis]

            def on_faces(x):
                return [lo + w * round((c - lo) / w) for c in x]

            for slabs in (2, 4):
                q = [(k + 1) / slabs for k in range(slabs - 1)]
                at_start = on_faces(np.quantile(particles[:, axis], q))
                rules = {
                    "particles": at_start,
                    "previous events": (
                        on_faces(np.quantile(previous[:, axis], q))
                        if previous is not None and len(previous)
                        else at_start
                    ),
                }
                for rule, cuts in rules.items():
                    counts = critical_path(events, cuts, w, axis)
                    t = totals.setdefault((axis, slabs, rule), [0] * 6)
                    for k, v in enumerate((len(events),) + counts + (1,)):
                        t[k] += v
        previous = events
    return totals


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        print(f"\n{path}\n")
        print(
            "| cut normal to | slabs | cuts at the quantiles of | events a flight "
            "| boundary events a flight | surprises a flight | best case, free sync "
            + "".join(f"| best case, sync = {b} events " for b in BARRIER_EVENTS)
            + f"| surprise windows redone, sync = {BARRIER_EVENTS[0]} events |"
        )
        print("|---" * (8 + len(BARRIER_EVENTS)) + "|")
        for (axis, slabs, rule), t in sorted(slab_statistics(path).items()):
            n, best, redone, nb, surprises, f = t
            row = f"| {'xy'[axis]} | {slabs} | {rule} | {n / f:.0f} | {nb / f:.1f} | {surprises / f:.1f} | {n / best:.2f} "
            row += "".join(f"| {n / (best + b * nb):.2f} " for b in BARRIER_EVENTS)
            row += f"| {n / (redone + BARRIER_EVENTS[0] * (nb + surprises)):.2f} "
            print(row + "|")


if __name__ == "__main__":
    main()
