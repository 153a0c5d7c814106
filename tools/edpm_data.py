#!/usr/bin/env python3
"""Reader for edpm's binary data files (docs/data-files.md): analysis
snapshots (`RUN_DIR/snapshots/NNNNNN.bin`, format version 3), checkpoints
(`final_state.bin`, format version 2) and restart files (`restart.bin`,
format version 5). Python standard library only (struct, zlib).

    import sys; sys.path.insert(0, "tools")
    from edpm_data import read_snapshot, read_checkpoint, read_snapshots, read_restart

    snap = read_snapshot("out/hcs-3d/snapshots/000004.bin")
    snap["time"], snap["run_id"], snap["lo"], snap["hi"]
    p = snap["particles"]            # columns: id, material, radius, mass, pos, vel, omega
    p["vel"][0]                      # (vx, vy, vz) of the first particle (m/s)
    snap["gas"]                      # None, or grid, gas_fraction, pressure, velocity
    snap["collisions"]               # None, or the collision tally of the interval

    for snap in read_snapshots("out/hcs-3d"):   # one run, in time order
        ...

    r = read_restart("out/riser-nonideal/restart.bin")
    r["time"], r["step"]             # absolute time (s), flow steps completed
    r["particles"]                   # id, material, radius, mass, pos, vel, omega
    r["gas"]                         # None, or cells, time, gas_fraction, pressure,
                                     # density, velocity (one list of face values per axis)

Tables are dicts from column name to a list (one entry per particle or
cell); 3-vectors are tuples. Every file's checksums are verified: a damaged
or truncated file raises DataFileError naming the file and the byte offset,
with the same words as edpm.

As a script, prints a one-line JSON summary of each file given:

    python3 tools/edpm_data.py out/hcs-3d/snapshots/000004.bin out/hcs-3d/final_state.bin
"""

import json
import os
import struct
import sys
import zlib

HEADER_BYTES = 48
CHUNK_BYTES = 4096

# kind: (magic, name in messages, version read, last version without the container)
SNAPSHOT = (b"EDPMSNAP", "snapshot", 3, 2)
CHECKPOINT = (b"EDPMCKPT", "checkpoint", 2, 1)
RESTART = (b"EDPMRST\0", "restart file", 5, 0)
KINDS = {SNAPSHOT[0]: SNAPSHOT, CHECKPOINT[0]: CHECKPOINT, RESTART[0]: RESTART}


class DataFileError(ValueError):
    """The file is not a readable edpm data file of the expected kind."""


def _container(path, data, kind):
    """Checks header, chunk checksums and length; returns (header, payload)."""
    magic, what, version_read, legacy_up_to = kind
    n = min(len(data), 8)
    if data[:n] != magic[:n]:
        old = struct.unpack_from("<I", data)[0] if len(data) >= 4 else 0
        if 1 <= old <= legacy_up_to:
            raise DataFileError(
                f"{path}: an edpm {what} of format version {old}, written by an older edpm "
                f"without checksums; this edpm reads version {version_read} only: run the "
                "scenario again to write it")
        shown = magic[:7].decode()
        raise DataFileError(f'{path}: not an edpm {what}: bytes 0..8 are not the magic "{shown}\\0"')
    if len(data) < HEADER_BYTES:
        raise DataFileError(f"{path}: truncated at byte offset {len(data)}: an edpm {what} "
                            f"starts with a {HEADER_BYTES}-byte header")
    (version, chunk, payload_len, run_id, chunks, _reserved, table_crc,
     header_crc) = struct.unpack_from("<IIQQIIII", data, 8)
    if zlib.crc32(data[:44]) != header_crc:
        raise DataFileError(f"{path}: checksum mismatch in the header (byte offsets 0..44): "
                            f"the {what} is damaged")
    if version != version_read:
        raise DataFileError(f"{path}: {what} format version {version} is not supported "
                            f"(this edpm reads version {version_read})")
    if chunk != CHUNK_BYTES or -(-payload_len // CHUNK_BYTES) != chunks:
        raise DataFileError(f"{path}: malformed header (chunk size {chunk}, {chunks} chunks "
                            f"for a payload of {payload_len} bytes)")
    start = HEADER_BYTES + 4 * chunks
    expected = start + payload_len
    if len(data) < expected:
        raise DataFileError(f"{path}: truncated at byte offset {len(data)}: the header "
                            f"announces {expected} bytes")
    if len(data) > expected:
        raise DataFileError(f"{path}: {len(data) - expected} unexpected bytes after the end "
                            f"of the {what} at byte offset {expected}")
    table = data[HEADER_BYTES:start]
    if zlib.crc32(table) != table_crc:
        raise DataFileError(f"{path}: checksum mismatch in the chunk table (byte offsets "
                            f"{HEADER_BYTES}..{start}): the {what} is damaged")
    crcs = struct.unpack(f"<{chunks}I", table)
    for k in range(chunks):
        a = start + k * CHUNK_BYTES
        b = min(a + CHUNK_BYTES, expected)
        if zlib.crc32(data[a:b]) != crcs[k]:
            raise DataFileError(f"{path}: checksum mismatch at byte offsets {a}..{b}: "
                                f"the {what} is damaged there")
    header = {"version": version, "run_id": f"{run_id:016x}", "payload_offset": start}
    return header, data[start:expected]


class _Cursor:
    """Sequential decoder of bincode (fixed-int, little-endian) values."""

    def __init__(self, path, what, data, offset):
        self.path, self.what, self.data, self.at, self.offset = path, what, data, 0, offset

    def take(self, n):
        if self.at + n > len(self.data):
            raise DataFileError(
                f"{self.path}: the {self.what} payload does not decode at byte offset "
                f"{self.offset + len(self.data)}: the data ends early "
                f"({self.at + n - len(self.data)} more bytes needed)")
        chunk = self.data[self.at:self.at + n]
        self.at += n
        return chunk

    def unpack(self, fmt):
        s = struct.Struct("<" + fmt)
        return s.unpack(self.take(s.size))

    def one(self, fmt):
        return self.unpack(fmt)[0]

    def vec3(self):
        return self.unpack("3d")

    def flag(self):
        v = self.one("B")
        if v > 1:
            raise DataFileError(f"{self.path}: the {self.what} payload does not decode at "
                                f"byte offset {self.offset + self.at - 1}: {v} is not a "
                                "boolean (0 or 1)")
        return v == 1

    def count(self, item_bytes):
        n = self.one("Q")
        if n * item_bytes > len(self.data) - self.at:
            raise DataFileError(f"{self.path}: the {self.what} payload does not decode at "
                                f"byte offset {self.offset + self.at - 8}: a length field "
                                "claims more bytes than the file holds")
        return n

    def floats(self):
        n = self.count(8)
        return list(self.unpack(f"{n}d"))

    def ints(self):
        n = self.count(8)
        return list(self.unpack(f"{n}Q"))

    def vec3s(self):
        n = self.count(24)
        flat = self.unpack(f"{3 * n}d")
        return [tuple(flat[3 * i:3 * i + 3]) for i in range(n)]

    def table(self, layout, fields):
        """u64 count, then packed rows of `layout`; {field: list}, vectors as tuples."""
        s = struct.Struct("<" + layout)
        n = self.count(s.size)
        rows = list(s.iter_unpack(self.take(n * s.size)))
        out, at = {}, 0
        for name, width in fields:
            if width == 1:
                out[name] = [r[at] for r in rows]
            else:
                out[name] = [tuple(r[at:at + width]) for r in rows]
            at += width
        return out

    def grid(self):
        return {"lo": self.vec3(), "h": self.vec3(), "n": self.unpack("3Q")}

    def done(self):
        if self.at != len(self.data):
            raise DataFileError(f"{self.path}: {len(self.data) - self.at} unexpected bytes "
                                f"inside the {self.what} payload at byte offset "
                                f"{self.offset + self.at}")


SNAPSHOT_PARTICLE = ("QHdd3d3d3d", [("id", 1), ("material", 1), ("radius", 1), ("mass", 1),
                                    ("pos", 3), ("vel", 3), ("omega", 3)])
CHECKPOINT_PARTICLE = ("3d3d3ddH", [("pos", 3), ("vel", 3), ("omega", 3), ("radius", 1),
                                    ("material", 1)])
TALLY_FIELDS = [("pair_collisions", "ints"), ("virial", "floats"),
                ("dissipated_normal", "floats"), ("dissipated_tangential", "floats"),
                ("pair_altered", "ints"), ("pair_undissipated", "floats"),
                ("wall_collisions", "ints"), ("wall_dissipated", "floats"),
                ("wall_altered", "ints"), ("wall_undissipated", "floats")]


def _read(path, kind):
    with open(path, "rb") as f:
        data = f.read()
    header, payload = _container(path, data, kind)
    return header, _Cursor(path, kind[1], payload, header["payload_offset"])


def read_snapshot(path):
    """Reads one analysis snapshot: a dict (docs/data-files.md, SI units)."""
    header, c = _read(path, SNAPSHOT)
    s = {"run_id": header["run_id"], "version": c.one("I")}
    if s["version"] != SNAPSHOT[2]:
        raise DataFileError(f"{path}: the payload says snapshot version {s['version']}, the "
                            f"header {SNAPSHOT[2]}: the snapshot is damaged")
    s["time"] = c.one("d")
    s["lo"], s["hi"] = c.vec3(), c.vec3()
    s["periodic"] = tuple(c.flag() for _ in range(3))
    s["planar"] = c.flag()
    s["gravity"] = c.vec3()
    s["particles"] = c.table(*SNAPSHOT_PARTICLE)
    s["gas"] = None
    if c.flag():
        s["gas"] = {"grid": c.grid(), "gas_fraction": c.floats(), "pressure": c.floats(),
                    "velocity": c.vec3s()}
    s["collisions"] = None
    if c.flag():
        tally = {"grid": c.grid(), "interval": c.one("d")}
        for name, kind in TALLY_FIELDS:
            tally[name] = getattr(c, kind)()
        s["collisions"] = tally
    c.done()
    return s


def read_checkpoint(path):
    """Reads a checkpoint (final_state.bin): run_id, version, time, particles."""
    header, c = _read(path, CHECKPOINT)
    cp = {"run_id": header["run_id"], "version": c.one("I")}
    if cp["version"] != CHECKPOINT[2]:
        raise DataFileError(f"{path}: the payload says checkpoint version {cp['version']}, "
                            f"the header {CHECKPOINT[2]}: the checkpoint is damaged")
    cp["time"] = c.one("d")
    cp["particles"] = c.table(*CHECKPOINT_PARTICLE)
    c.done()
    return cp


# One engine slot of a restart file: pos, vel, omega, radius, inverse mass,
# material, id, active, event counter, shell centre and reach, face mask,
# cell, last collision time, last partner slot.
RESTART_SLOT = struct.Struct("<3d3d3dddHQ?I3ddB3QdI")
GAS_CELL_FIELDS = ["gas_fraction", "gas_fraction_old", "pressure", "density", "density_old"]
GAS_FACE_FIELDS = ["velocity", "drag_beta", "drag_alpha", "pressure_share", "eps_face_old",
                   "explicit", "coefficient", "mass_flux"]


def read_restart(path):
    """Reads a restart file's time, particles and gas fields (docs/data-files.md).

    The engine's internals that follow (neighbour lists, cells, random
    streams, counters) are checked by the checksums but not decoded."""
    header, c = _read(path, RESTART)
    r = {"run_id": header["run_id"], "version": header["version"],
         "scenario": f"{c.one('Q'):016x}", "time": c.one("d"), "step": c.one("Q")}
    n = c.count(RESTART_SLOT.size)
    cols = {k: [] for k in ("id", "material", "radius", "mass", "pos", "vel", "omega")}
    for row in RESTART_SLOT.iter_unpack(c.take(n * RESTART_SLOT.size)):
        if not row[13]:  # a free slot
            continue
        cols["pos"].append(row[0:3])
        cols["vel"].append(row[3:6])
        cols["omega"].append(row[6:9])
        cols["radius"].append(row[9])
        cols["mass"].append(1.0 / row[10])
        cols["material"].append(row[11])
        cols["id"].append(row[12])
    r["particles"] = cols
    r["gas"] = None
    if c.flag():
        gas = {"cells": c.unpack("3Q"), "time": c.one("d")}
        for name in GAS_CELL_FIELDS:
            gas[name] = c.floats()
        for name in GAS_FACE_FIELDS:
            gas[name] = [c.floats() for _ in range(3)]
        r["gas"] = gas
    return r


def read_snapshots(run_dir):
    """Every snapshot of a run directory, in time order; refuses a mix of runs."""
    d = os.path.join(run_dir, "snapshots")
    names = sorted(n for n in os.listdir(d) if n.endswith(".bin"))
    snaps = [read_snapshot(os.path.join(d, n)) for n in names]
    for n, s in zip(names, snaps):
        if s["run_id"] != snaps[0]["run_id"]:
            raise DataFileError(f"{os.path.join(d, n)}: written by run {s['run_id']}, but "
                                f"{os.path.join(d, names[0])} by run {snaps[0]['run_id']}: "
                                "the directory holds snapshots of different runs")
    return snaps


def read_file(path):
    """A snapshot, checkpoint or restart file, by its magic; adds "kind" to the dict."""
    with open(path, "rb") as f:
        magic = f.read(8)
    kind = KINDS.get(magic, SNAPSHOT)
    reader = {SNAPSHOT: read_snapshot, CHECKPOINT: read_checkpoint, RESTART: read_restart}
    out = reader[kind](path)
    out["kind"] = kind[1]
    return out


def _row(table, i):
    return {k: v[i] for k, v in table.items()}


def summary(d):
    """The one-line summary printed by the script, as a dict."""
    p = d["particles"]
    n = len(p["radius"])
    out = {"kind": d["kind"], "version": d["version"], "run_id": d["run_id"],
           "time": d["time"], "particles": n,
           "first": _row(p, 0) if n else None, "last": _row(p, n - 1) if n else None}
    if d["kind"] != "checkpoint":
        out["gas_cells"] = len(d["gas"]["pressure"]) if d["gas"] else None
    if d["kind"] == "restart file":
        out["step"] = d["step"]
        out["gas_pressure_first"] = d["gas"]["pressure"][0] if d["gas"] else None
    if d["kind"] == "snapshot":
        t = d["collisions"]
        out["pair_collisions"] = sum(t["pair_collisions"]) if t else None
        out["wall_collisions"] = sum(t["wall_collisions"]) if t else None
    return out


def main(argv):
    if len(argv) < 2:
        print(f"usage: {argv[0]} FILE...", file=sys.stderr)
        return 2
    for path in argv[1:]:
        try:
            print(json.dumps(summary(read_file(path))))
        except (DataFileError, OSError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
