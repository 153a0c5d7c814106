#!/usr/bin/env python3
"""Reader for edpm binary event logs (format versions 2 and 3, docs/event-log.md).

    from edpm_log import read_log
    log = read_log("run.log")
    log["records"]["kind"], log["checkpoints"][-1], log["initial"]["pos"], ...
    log["sets"]     # velocities and states blocks (version 3: gas, soft, hybrid
                    # runs): (kind "velocities" or "states", time, clock, table)

With numpy installed, tables (records, checkpoint particles, initial
particles) are numpy structured arrays and `densities` is an array.
Without numpy, or with `read_log(path, use_numpy=False)`, the standard
library alone (`struct`) decodes the same file into columns: each table is
a dict from field name to a list (one entry per row; 3- and 9-vectors are
tuples), so `log["records"]["kind"]` works either way.

As a script, prints a one-line JSON summary of a log (`--no-numpy` forces
the standard-library path):

    python3 tools/edpm_log.py [--no-numpy] run.log
"""

import json
import struct
import sys
import warnings
import zlib

try:
    import numpy as np
except ImportError:  # the standard-library path below needs nothing else
    np = None

FORMAT_VERSION = 3
OLDEST_READ_VERSION = 2
FILE_MAGIC = b"EDPMLOG\0"
BLOCK_MAGIC = b"BLK\0"
FILE_HEADER_BYTES = 32
BLOCK_HEADER_BYTES = 24
CHECKPOINT_HEADER_BYTES = 24
KIND_RECORDS, KIND_CHECKPOINT, KIND_END, KIND_VELOCITIES, KIND_STATES, KIND_GAS = range(1, 7)
END_BYTES = 16
SET_HEADER_BYTES = 16
VELOCITY_ENTRY_BYTES, STATE_ENTRY_BYTES = 32, 80

# Record kinds (LogRecord.kind) and collision branches (LogRecord.aux).
PAIR, WALL, WRAP, INSERT, REMOVE, FLOW_STEP_END, KICK = range(1, 8)
KIND_NAMES = {PAIR: "pair", WALL: "wall", WRAP: "wrap", INSERT: "insert",
              REMOVE: "remove", FLOW_STEP_END: "flow-step-end", KICK: "kick"}
BRANCH_NAMES = {0: "smooth", 1: "sticking", 2: "sliding"}
AXIS_BOUNDARIES = ("walls", "periodic", "frozen")
OUTLET_MODES = ("remove", "reinsert")

RECORD_BYTES = 184
# A checkpoint particle: 96 bytes.
PARTICLE_BYTES = 96
# One entry of LogHeader.initial: (id, NewParticle), packed (90 bytes).
INITIAL_BYTES = 90

# Standard-library layouts: (struct format, [(field, number of values)]).
RECORD_STRUCT = struct.Struct("<IIddQQ9d9d")
RECORD_FIELDS = [("kind", 1), ("aux", 1), ("time", 1), ("clock", 1),
                 ("a", 1), ("b", 1), ("state_a", 9), ("state_b", 9)]
PARTICLE_STRUCT = struct.Struct("<QIId9d")
PARTICLE_FIELDS = [("id", 1), ("material", 1), ("reserved", 1), ("radius", 1), ("state", 9)]
VELOCITY_STRUCT = struct.Struct("<Q3d")
VELOCITY_FIELDS = [("id", 1), ("vel", 3)]
STATE_STRUCT = struct.Struct("<Q9d")
STATE_FIELDS = [("id", 1), ("state", 9)]
INITIAL_STRUCT = struct.Struct("<Q3d3d3ddH")
INITIAL_FIELDS = [("id", 1), ("pos", 3), ("vel", 3), ("omega", 3), ("radius", 1),
                  ("material", 1)]
assert RECORD_STRUCT.size == RECORD_BYTES and PARTICLE_STRUCT.size == PARTICLE_BYTES
assert INITIAL_STRUCT.size == INITIAL_BYTES

if np is not None:
    RECORD_DTYPE = np.dtype([
        ("kind", "<u4"), ("aux", "<u4"), ("time", "<f8"), ("clock", "<f8"),
        ("a", "<u8"), ("b", "<u8"), ("state_a", "<f8", (9,)), ("state_b", "<f8", (9,)),
    ])
    PARTICLE_DTYPE = np.dtype({
        "names": ["id", "material", "reserved", "radius", "state"],
        "formats": ["<u8", "<u4", "<u4", "<f8", ("<f8", (9,))],
        "offsets": [0, 8, 12, 16, 24],
        "itemsize": PARTICLE_BYTES,
    })
    INITIAL_DTYPE = np.dtype([
        ("id", "<u8"), ("pos", "<f8", (3,)), ("vel", "<f8", (3,)),
        ("omega", "<f8", (3,)), ("radius", "<f8"), ("material", "<u2"),
    ])
    assert RECORD_DTYPE.itemsize == RECORD_BYTES and PARTICLE_DTYPE.itemsize == PARTICLE_BYTES
    assert INITIAL_DTYPE.itemsize == INITIAL_BYTES


def _columns(layout, fields, data):
    """Decodes packed rows of `layout` into {field: list}; vectors as tuples."""
    rows = list(layout.iter_unpack(data))
    out = {}
    at = 0
    for name, width in fields:
        if width == 1:
            out[name] = [row[at] for row in rows]
        else:
            out[name] = [tuple(row[at:at + width]) for row in rows]
        at += width
    return out


def _concat_columns(tables, fields):
    out = {name: [] for name, _ in fields}
    for t in tables:
        for name, _ in fields:
            out[name].extend(t[name])
    return out


class LogError(ValueError):
    """The file is not a readable version-2 edpm event log."""


class _Cursor:
    """Sequential decoder of bincode (fixed-int, little-endian) values."""

    def __init__(self, data, use_numpy):
        self.data, self.at, self.use_numpy = data, 0, use_numpy

    def take(self, n):
        if self.at + n > len(self.data):
            raise LogError("file header payload ends early")
        chunk = self.data[self.at:self.at + n]
        self.at += n
        return chunk

    def scalar(self, fmt):
        return struct.unpack("<" + fmt, self.take(struct.calcsize(fmt)))[0]

    def string(self):
        return self.take(self.scalar("Q")).decode("utf-8")

    def floats(self, count):
        data = self.take(8 * count)
        if self.use_numpy:
            return np.frombuffer(data, "<f8").copy()
        return list(struct.unpack(f"<{count}d", data))

    def initial(self, count):
        data = self.take(INITIAL_BYTES * count)
        if self.use_numpy:
            return np.frombuffer(data, INITIAL_DTYPE).copy()
        return _columns(INITIAL_STRUCT, INITIAL_FIELDS, data)


def _decode_header(payload, use_numpy):
    c = _Cursor(payload, use_numpy)
    h = {"writer": c.string(), "scenario_text": c.string()}
    h["overrides"] = [c.string() for _ in range(c.scalar("Q"))]
    h["seed"] = c.scalar("Q")
    h["dt_flow"] = c.scalar("d")
    domain = {"lo": list(struct.unpack("<3d", c.take(24))),
              "hi": list(struct.unpack("<3d", c.take(24))),
              "axes": [AXIS_BOUNDARIES[i] for i in struct.unpack("<3I", c.take(12))],
              "outlet": None}
    if c.scalar("B") == 1:
        domain["outlet"] = {"axis": c.scalar("Q"), "mode": OUTLET_MODES[c.scalar("I")]}
    h["domain"] = domain
    h["densities"] = c.floats(c.scalar("Q"))
    h["initial"] = c.initial(c.scalar("Q"))
    if c.at != len(payload):
        raise LogError(f"file header payload has {len(payload) - c.at} unexpected trailing bytes")
    return h


def read_log(path, use_numpy=None):
    """Reads a whole log: header fields, records, checkpoints.

    Returns a dict with the decoded LogHeader fields (writer, scenario_text,
    overrides, seed, dt_flow, domain, densities, initial), plus version,
    records (all record blocks, in file order), checkpoints (list of
    (time, clock, step, particles)), truncated_at (byte offset of an
    incomplete final block, or None), end (the end block as
    {"records", "time"}, None for a log without one: a killed run, with a
    warning) and reader ("numpy" or "struct").
    Tables are numpy structured arrays (RECORD_DTYPE, PARTICLE_DTYPE,
    INITIAL_DTYPE) when numpy is used, else dicts of column lists.
    use_numpy: None uses numpy when it is installed; False never does;
    True requires it.
    Raises LogError on a bad magic, an unsupported version, a checksum
    mismatch, a missing block (a gap in the block sequence numbers) or a
    malformed block.
    """
    if use_numpy is None:
        use_numpy = np is not None
    if use_numpy and np is None:
        raise ImportError("numpy is not installed; use read_log(path, use_numpy=False)")
    with open(path, "rb") as f:
        data = memoryview(f.read())  # slices of a memoryview do not copy
    if len(data) < FILE_HEADER_BYTES or bytes(data[:8]) != FILE_MAGIC:
        raise LogError(f"{path}: not an edpm event log (bad magic)")
    version, length, crc = struct.unpack_from("<3I", data, 8)
    if version == 1:
        raise LogError(f"{path}: event log format version 1 (written by an older edpm, without "
                       f"block sequence numbers) is no longer read; this reader reads versions "
                       f"{OLDEST_READ_VERSION} to {FORMAT_VERSION}: run the scenario again with --log")
    if not OLDEST_READ_VERSION <= version <= FORMAT_VERSION:
        raise LogError(f"{path}: event log format version {version} is not supported "
                       f"(this reader reads versions {OLDEST_READ_VERSION} to {FORMAT_VERSION})")
    end = FILE_HEADER_BYTES + length
    if len(data) < end:
        raise LogError(f"{path}: file header is truncated")
    payload = data[FILE_HEADER_BYTES:end]
    if zlib.crc32(payload) != crc:
        raise LogError(f"{path}: checksum mismatch in file header at byte offset {FILE_HEADER_BYTES}")
    try:
        log = {"version": version, **_decode_header(bytes(payload), use_numpy)}
    except (IndexError, UnicodeDecodeError, struct.error) as e:
        raise LogError(f"{path}: malformed file header ({e})") from None

    record_blocks, checkpoints, sets, gas_times = [], [], [], []
    truncated_at, end_block = None, None
    at = end
    seq_expected = 0
    while at < len(data):
        if len(data) - at < BLOCK_HEADER_BYTES:
            truncated_at = at
            break
        magic, kind, count, length, crc, seq = struct.unpack_from("<4s5I", data, at)
        if bytes(magic) != BLOCK_MAGIC:
            raise LogError(f"{path}: malformed block header at byte offset {at}")
        # Kind, count and length must agree before a short file counts as
        # truncation: the block header has no checksum of its own.
        if not ((kind == KIND_RECORDS and length == count * RECORD_BYTES) or
                (kind == KIND_CHECKPOINT and length == CHECKPOINT_HEADER_BYTES + count * PARTICLE_BYTES) or
                (kind == KIND_END and length == END_BYTES and count == 0) or
                (kind == KIND_VELOCITIES and length == SET_HEADER_BYTES + count * VELOCITY_ENTRY_BYTES) or
                (kind == KIND_STATES and length == SET_HEADER_BYTES + count * STATE_ENTRY_BYTES) or
                (kind == KIND_GAS and length >= count * 24)):
            raise LogError(f"{path}: malformed block (unknown kind or size) at byte offset {at}")
        body = at + BLOCK_HEADER_BYTES
        if len(data) - body < length:
            truncated_at = at
            break
        payload = data[body:body + length]
        # The CRC covers kind, count, length (bytes 4..16), the sequence
        # number (20..24) and the payload.
        header_crc = zlib.crc32(data[at + 20:at + 24], zlib.crc32(data[at + 4:at + 16]))
        if zlib.crc32(payload, header_crc) != crc:
            raise LogError(f"{path}: checksum mismatch in block at byte offset {at}: "
                           "the log is corrupted from there on")
        if seq != seq_expected:
            raise LogError(f"{path}: block {seq_expected} is missing: the block at byte offset "
                           f"{at} is block {seq}; the log was cut or spliced there")
        seq_expected += 1
        if kind == KIND_END:
            if body + length != len(data):
                raise LogError(f"{path}: malformed log: {len(data) - body - length} bytes after "
                               f"the end block at byte offset {body + length}")
            records, time = struct.unpack_from("<Qd", payload)
            end_block = {"records": records, "time": time}
            at = body + length
            break
        if kind == KIND_GAS:
            # The gas fields at a checkpoint (bincode; see docs/event-log.md):
            # only their time is decoded here.
            gas_times.append(struct.unpack_from("<d", payload)[0])
        elif kind in (KIND_VELOCITIES, KIND_STATES):
            time, clock = struct.unpack_from("<2d", payload)
            layout = ((VELOCITY_STRUCT, VELOCITY_FIELDS) if kind == KIND_VELOCITIES
                      else (STATE_STRUCT, STATE_FIELDS))
            table = _columns(*layout, payload[SET_HEADER_BYTES:])
            name = "velocities" if kind == KIND_VELOCITIES else "states"
            sets.append((name, time, clock, table))
        elif kind == KIND_RECORDS:
            if use_numpy:
                record_blocks.append(np.frombuffer(payload, RECORD_DTYPE))
            else:
                record_blocks.append(_columns(RECORD_STRUCT, RECORD_FIELDS, payload))
        else:
            time, clock, step = struct.unpack_from("<2dQ", payload)
            body_bytes = payload[CHECKPOINT_HEADER_BYTES:]
            if use_numpy:
                particles = np.frombuffer(body_bytes, PARTICLE_DTYPE).copy()
            else:
                particles = _columns(PARTICLE_STRUCT, PARTICLE_FIELDS, body_bytes)
            checkpoints.append((time, clock, step, particles))
        at = body + length
    if truncated_at is not None:
        warnings.warn(f"{path}: truncated log, the incomplete block at byte offset "
                      f"{truncated_at} and everything after it are ignored", stacklevel=2)
    elif end_block is None:
        warnings.warn(f"{path}: no end block after byte offset {at}: the run that wrote it was "
                      "killed, or the blocks after that offset are missing", stacklevel=2)
    if use_numpy:
        log["records"] = (np.concatenate(record_blocks) if record_blocks
                          else np.zeros(0, RECORD_DTYPE))
    else:
        log["records"] = _concat_columns(record_blocks, RECORD_FIELDS)
    log["checkpoints"] = checkpoints
    log["sets"] = sets
    log["gas_times"] = gas_times
    log["truncated_at"] = truncated_at
    log["end"] = end_block
    log["reader"] = "numpy" if use_numpy else "struct"
    return log


def _count(values, wanted):
    if np is not None and isinstance(values, np.ndarray):
        return int(np.count_nonzero(values == wanted))
    return sum(1 for v in values if v == wanted)


def summary(log):
    """The one-line summary printed by the script, as a dict."""
    kinds = log["records"]["kind"]
    times = [float(log["records"]["time"][-1])] if len(kinds) else []
    times += [cp[0] for cp in log["checkpoints"][-1:]]
    return {
        "version": log["version"],
        "reader": log["reader"],
        "records": int(len(kinds)),
        "pair_collisions": _count(kinds, PAIR),
        "wall_collisions": _count(kinds, WALL),
        "checkpoints": len(log["checkpoints"]),
        "velocities_blocks": sum(1 for s in log["sets"] if s[0] == "velocities"),
        "states_blocks": sum(1 for s in log["sets"] if s[0] == "states"),
        "t_last": max(times) if times else None,
        "complete": log["end"] is not None,
    }


def main(argv):
    args = argv[1:]
    use_numpy = None
    if args[:1] == ["--no-numpy"]:
        use_numpy, args = False, args[1:]
    if len(args) != 1:
        print(f"usage: {argv[0]} [--no-numpy] LOG", file=sys.stderr)
        return 2
    try:
        log = read_log(args[0], use_numpy)
    except (LogError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(summary(log)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
