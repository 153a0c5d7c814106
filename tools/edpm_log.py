#!/usr/bin/env python3
"""Reader for edpm binary event logs (format version 1, docs/event-log.md).

    from edpm_log import read_log
    log = read_log("run.log")
    log["records"]["kind"], log["checkpoints"][-1], log["initial"]["pos"], ...

As a script, prints a one-line JSON summary of a log:

    python3 tools/edpm_log.py run.log
"""

import json
import struct
import sys
import warnings
import zlib

import numpy as np

FORMAT_VERSION = 1
FILE_MAGIC = b"EDPMLOG\0"
BLOCK_MAGIC = b"BLK\0"
FILE_HEADER_BYTES = 32
BLOCK_HEADER_BYTES = 24
CHECKPOINT_HEADER_BYTES = 24
KIND_RECORDS, KIND_CHECKPOINT = 1, 2

# Record kinds (LogRecord.kind) and collision branches (LogRecord.aux).
PAIR, WALL, WRAP, INSERT, REMOVE, FLOW_STEP_END, KICK = range(1, 8)
KIND_NAMES = {PAIR: "pair", WALL: "wall", WRAP: "wrap", INSERT: "insert",
              REMOVE: "remove", FLOW_STEP_END: "flow-step-end", KICK: "kick"}
BRANCH_NAMES = {0: "smooth", 1: "sticking", 2: "sliding"}
AXIS_BOUNDARIES = ("walls", "periodic", "frozen")
OUTLET_MODES = ("remove", "reinsert")

RECORD_DTYPE = np.dtype([
    ("kind", "<u4"), ("aux", "<u4"), ("time", "<f8"), ("clock", "<f8"),
    ("a", "<u8"), ("b", "<u8"), ("state_a", "<f8", (9,)), ("state_b", "<f8", (9,)),
])
# A checkpoint particle: 96 bytes.
PARTICLE_BYTES = 96
PARTICLE_DTYPE = np.dtype({
    "names": ["id", "material", "reserved", "radius", "state"],
    "formats": ["<u8", "<u4", "<u4", "<f8", ("<f8", (9,))],
    "offsets": [0, 8, 12, 16, 24],
    "itemsize": PARTICLE_BYTES,
})
# One entry of LogHeader.initial: (id, NewParticle), packed (90 bytes).
INITIAL_DTYPE = np.dtype([
    ("id", "<u8"), ("pos", "<f8", (3,)), ("vel", "<f8", (3,)),
    ("omega", "<f8", (3,)), ("radius", "<f8"), ("material", "<u2"),
])
assert RECORD_DTYPE.itemsize == 184 and PARTICLE_DTYPE.itemsize == 96
assert INITIAL_DTYPE.itemsize == 90


class LogError(ValueError):
    """The file is not a readable version-1 edpm event log."""


class _Cursor:
    """Sequential decoder of bincode (fixed-int, little-endian) values."""

    def __init__(self, data):
        self.data, self.at = data, 0

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

    def array(self, dtype, count):
        dtype = np.dtype(dtype)
        return np.frombuffer(self.take(dtype.itemsize * count), dtype).copy()


def _decode_header(payload):
    c = _Cursor(payload)
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
    h["densities"] = c.array("<f8", c.scalar("Q"))
    h["initial"] = c.array(INITIAL_DTYPE, c.scalar("Q"))
    if c.at != len(payload):
        raise LogError(f"file header payload has {len(payload) - c.at} unexpected trailing bytes")
    return h


def read_log(path):
    """Reads a whole log: header fields, records, checkpoints.

    Returns a dict with the decoded LogHeader fields (writer, scenario_text,
    overrides, seed, dt_flow, domain, densities, initial), plus version,
    records (RECORD_DTYPE array over all record blocks, in file order),
    checkpoints (list of (time, clock, step, PARTICLE_DTYPE array)) and
    truncated_at (byte offset of an incomplete final block, or None).
    Raises LogError on a bad magic, an unsupported version, a checksum
    mismatch or a malformed block.
    """
    with open(path, "rb") as f:
        data = memoryview(f.read())  # slices of a memoryview do not copy
    if len(data) < FILE_HEADER_BYTES or bytes(data[:8]) != FILE_MAGIC:
        raise LogError(f"{path}: not an edpm event log (bad magic)")
    version, length, crc = struct.unpack_from("<3I", data, 8)
    if version != FORMAT_VERSION:
        raise LogError(f"{path}: event log format version {version} is not supported "
                       f"(this reader reads version {FORMAT_VERSION})")
    end = FILE_HEADER_BYTES + length
    if len(data) < end:
        raise LogError(f"{path}: file header is truncated")
    payload = data[FILE_HEADER_BYTES:end]
    if zlib.crc32(payload) != crc:
        raise LogError(f"{path}: checksum mismatch in file header at byte offset {FILE_HEADER_BYTES}")
    try:
        log = {"version": version, **_decode_header(bytes(payload))}
    except (IndexError, UnicodeDecodeError) as e:
        raise LogError(f"{path}: malformed file header ({e})") from None

    record_blocks, checkpoints, truncated_at = [], [], None
    at = end
    while at < len(data):
        if len(data) - at < BLOCK_HEADER_BYTES:
            truncated_at = at
            break
        magic, kind, count, length, crc = struct.unpack_from("<4s4I", data, at)
        if bytes(magic) != BLOCK_MAGIC:
            raise LogError(f"{path}: malformed block header at byte offset {at}")
        # Kind, count and length must agree before a short file counts as
        # truncation: the block header has no checksum of its own.
        if not ((kind == KIND_RECORDS and length == count * RECORD_DTYPE.itemsize) or
                (kind == KIND_CHECKPOINT and length == CHECKPOINT_HEADER_BYTES + count * PARTICLE_BYTES)):
            raise LogError(f"{path}: malformed block (unknown kind or size) at byte offset {at}")
        body = at + BLOCK_HEADER_BYTES
        if len(data) - body < length:
            truncated_at = at
            break
        payload = data[body:body + length]
        if zlib.crc32(payload) != crc:
            raise LogError(f"{path}: checksum mismatch in block at byte offset {at}: "
                           "the log is corrupted from there on")
        if kind == KIND_RECORDS:
            record_blocks.append(np.frombuffer(payload, RECORD_DTYPE))
        else:
            time, clock, step = struct.unpack_from("<2dQ", payload)
            particles = np.frombuffer(payload, PARTICLE_DTYPE, offset=CHECKPOINT_HEADER_BYTES).copy()
            checkpoints.append((time, clock, step, particles))
        at = body + length
    if truncated_at is not None:
        warnings.warn(f"{path}: truncated log, the incomplete block at byte offset "
                      f"{truncated_at} and everything after it are ignored", stacklevel=2)
    log["records"] = np.concatenate(record_blocks) if record_blocks else np.zeros(0, RECORD_DTYPE)
    log["checkpoints"] = checkpoints
    log["truncated_at"] = truncated_at
    return log


def summary(log):
    """The one-line summary printed by the script, as a dict."""
    kinds = log["records"]["kind"]
    times = [float(log["records"]["time"][-1])] if len(kinds) else []
    times += [cp[0] for cp in log["checkpoints"][-1:]]
    return {
        "version": log["version"],
        "records": int(len(kinds)),
        "pair_collisions": int(np.count_nonzero(kinds == PAIR)),
        "wall_collisions": int(np.count_nonzero(kinds == WALL)),
        "checkpoints": len(log["checkpoints"]),
        "t_last": max(times) if times else None,
    }


def main(argv):
    if len(argv) != 2:
        print(f"usage: {argv[0]} LOG", file=sys.stderr)
        return 2
    try:
        log = read_log(argv[1])
    except (LogError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(summary(log)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
