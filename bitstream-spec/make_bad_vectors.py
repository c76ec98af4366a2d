#!/usr/bin/env python3
"""Writes the bad conformance vectors `vectors/bad/bad-*.gsc` and `vectors/bad/EXPECTED`
(SPEC §9.2), and the good vector `vectors/quirks.gsc` with its `quirks.ply` (SPEC §9.3),
deterministically from the good vectors `vectors/hand.gsc`, (for the levels section of
format 4.0, SPEC §3.1) `vectors/levels.gsc`, (for the codebooks of format 5.0, SPEC §3.2)
`vectors/vq.gsc`, (for the parameter sections per level of format 6.0, SPEC §4)
`vectors/classes.gsc`, (for the anchor profile of format 7.0, SPEC §12) `vectors/anchor.gsc`,
(for the neighbour-context tables of format 8.0, SPEC §4.3) `vectors/neighbour.gsc` and (for the
shared index of format 9.0, SPEC §3.2) `vectors/shared.gsc`.

Each bad vector breaks exactly one rule of SPEC.md; every other byte, including every CRC that
is not the point of the vector, is kept valid, so that a decoder has to reach the broken rule
to refuse the file. Streams are re-coded with the encoder of SPEC §5.4, written here from the
SPEC text. Parsing uses specdec.py (the SPEC's second decoder), so this needs numpy.

Usage: python3 make_bad_vectors.py [--out DIR]   (no argument: rewrites vectors/bad/,
       quirks.gsc, quirks.ply and their lines in SHA256SUMS; --out: writes the bad vectors,
       EXPECTED and quirks.gsc to DIR only)
"""
import hashlib
import os
import struct
import sys
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import specdec  # noqa: E402

VECTORS = os.path.join(HERE, "vectors")
BAD = os.path.join(VECTORS, "bad")


# ----------------------------------------------------------------------------
# Writing (SPEC §1, §2, §4.1, §5.4)
# ----------------------------------------------------------------------------
def varint(v):
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def zigzag(v):
    return ((v << 1) ^ (v >> 31)) & 0xFFFFFFFF


class File:
    """A parsed .gsc file that can be changed and written again with valid CRCs."""

    def __init__(self, data):
        self.major, self.minor = data[4], data[5]
        _, self.n, self.degree, sections = specdec.parse_container(data)
        self.flags = self.reserved = 0
        # [kind, chunk, flags, payload, crc or None (= correct)]
        self.sections = [[k, c, f, p, None] for (k, c), (f, p) in sections.items()]

    def section(self, kind, chunk=0):
        return next(s for s in self.sections if s[0] == kind and s[1] == chunk)

    def remove(self, kind, chunk=0):
        self.sections.remove(self.section(kind, chunk))

    def write(self, header_crc_xor=0, length_delta=None):
        """length_delta: (index, delta) adds delta to one table entry's length field only."""
        head = bytearray(b"\x8aGSC")
        head += struct.pack("<BBHIBBH", self.major, self.minor, len(self.sections), self.n,
                            self.degree, self.flags, self.reserved)
        for i, (kind, chunk, flags, payload, crc) in enumerate(self.sections):
            length = len(payload) + (length_delta[1] if length_delta and length_delta[0] == i else 0)
            crc = zlib.crc32(payload) if crc is None else crc
            head += struct.pack("<HHIII", kind, chunk, flags, length, crc)
        head += struct.pack("<I", zlib.crc32(head) ^ header_crc_xor)
        return bytes(head) + b"".join(s[3] for s in self.sections)


def ans_encode(intervals, start=0):
    """SPEC §5.4: the stream of `intervals` [(cdf, freq)] given in decode order. `start` is the
    encoder's initial state; a conforming encoder starts at 0 (bad-final-state starts at 1)."""
    x, out = start, []
    for c, f in reversed(intervals):
        if x >= f << 48:
            out.append(x & 0xFFFFFFFF)
            x >>= 32
        x = ((x // f) << 16) + c + x % f
    head = [] if x == 0 else [x] if x < 1 << 32 else [x >> 32, x & 0xFFFFFFFF]
    return struct.pack(f"<{len(head) + len(out)}I", *head, *reversed(out))


def raw_intervals(value, bits):
    """§5.1: `bits` raw bits, most significant piece (of at most 16 bits) first."""
    out, left = [], bits
    while left > 0:
        take = min(left, 16)
        left -= take
        piece = (value >> left) & ((1 << take) - 1)
        out.append((piece << (16 - take), 1 << (16 - take)))
    return out


def value_intervals(table, values):
    """§5.2: the intervals coding the values of one stream with a coded or context table."""
    out, prev = [], table.centre
    for v in values:
        cdf = specdec.table_for(table, prev)
        s = v - table.lo if 0 <= v - table.lo < table.n else table.n
        out.append((cdf[s], cdf[s + 1] - cdf[s]))
        if s == table.n:
            out += raw_intervals(zigzag(v), 32)
        prev = v
    return out


def overlong(v):
    """`v` as a 5-byte varint (§1: valid, though encoders write the shortest form)."""
    return bytes([(v >> (7 * i)) & 0x7F | (0x80 if i < 4 else 0) for i in range(5)])


def streams_of(payload, count):
    """The `count` streams of a data section (§6)."""
    return specdec.split_streams(payload, count, "section")


def section_of(streams):
    return b"".join(varint(len(s)) + s for s in streams)


def decoded_values(stream, table, k):
    dec = specdec.AnsDecoder(stream, "stream")
    state = [table.centre]
    values = [specdec.read_value(dec, table, state) for _ in range(k)]
    dec.finish()
    return values


def replace_table(params, index, new_table_bytes):
    """Parameter section of a non-position group with channel `index`'s table replaced."""
    rd = specdec.Reader(params, "params")
    out = bytearray([rd.u8()])
    for j in range(params[0]):
        step = rd.take(4)
        start = rd.pos
        specdec.read_channel_table(rd, allow_context=True, allow_neighbour=True)
        out += step + (new_table_bytes if j == index else params[start:rd.pos])
    return bytes(out)


def replace_step(params, index, step):
    """Parameter section of a non-position group with channel `index`'s step replaced."""
    rd = specdec.Reader(params, "params")
    rd.u8()
    for j in range(index + 1):
        at = rd.pos
        rd.take(4)
        specdec.read_channel_table(rd, allow_context=True)
    return params[:at] + struct.pack("<f", step) + params[at + 4:]


# ----------------------------------------------------------------------------
# The bad vectors
# ----------------------------------------------------------------------------
def make(good):
    """{name: (bytes, class, reason)}."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    def edit():
        return File(good)

    # hand.gsc: N = 3, D = 1; group g's parameters are kind 0x10+g, its data 0x20+g (chunk 0).
    k = 3
    rot_params = specdec.parse_group_params(2, File(good).section(0x12)[3])
    opa_params = specdec.parse_group_params(3, File(good).section(0x13)[3])
    origin, step, bits, length_table = specdec.parse_position_params(File(good).section(0x10)[3])

    # --- container (§2) ---
    add("truncated", good[: len(good) - 7], "format", "the file ends 7 bytes before the last payload does")
    add("magic", b"\x8aGSD" + good[4:], "format", "magic is 8A 47 53 44, not 8A 47 53 43")
    f = edit()
    f.major = 10
    add("version", f.write(), "unsupported", "version_major 10 (header CRC valid)")
    add("header-crc", edit().write(header_crc_xor=1), "checksum", "header CRC off by one bit")
    f = edit()
    s = f.section(0x24)
    s[4] = zlib.crc32(s[3]) ^ 0x80000000
    add("section-crc", f.write(), "checksum", "CRC of the sh_dc data section off by one bit")
    f = edit()
    f.sections.append([0x102, 0, 1, b"skip me", zlib.crc32(b"skip me") ^ 1])
    add("skipped-crc", f.write(), "checksum",
        "an unknown section with the optional bit set (which a decoder skips) has a wrong CRC")
    f = edit()
    f.sections.append([0x102, 0, 0, b"must understand", None])
    add("unknown-section", f.write(), "unsupported", "section kind 0x102 without the optional bit")
    f = edit()
    f.section(0x13)[2] = 2
    add("section-flags", f.write(), "format", "section flags bit 1 set")
    f = edit()
    f.sections.append(list(f.section(0x100)))
    add("duplicate-section", f.write(), "format", "the info section (0x100, 0) listed twice")
    f = edit()
    f.n = (1 << 26) + 1
    add("count-limit", f.write(), "limits", "N = 2^26 + 1")
    f = edit()
    f.n = 8 * len(good) + 1
    add("count-file", f.write(), "limits", "N = 8 * file length + 1 (allocation bound)")
    f = edit()
    add("section-beyond-file", f.write(length_delta=(len(f.sections) - 1, 1000)), "format",
        "the last table entry declares 1000 bytes more than the file holds (truncation)")
    add("trailing", good + b"\x00", "format", "one byte after the last payload")
    f = edit()
    f.degree = 4
    add("sh-degree", f.write(), "format", "SH degree 4")
    f = edit()
    f.remove(0x13)
    add("missing-params", f.write(), "format", "the opacity parameter section is absent")
    f = edit()
    f.remove(0x23)
    add("missing-data", f.write(), "format",
        "the opacity data section is absent although its channel is coded (truncation)")

    # --- parameters and tables (§1, §4) ---
    f = edit()
    s = f.section(0x10)
    s[3] = struct.pack("<f", float("inf")) + s[3][4:]
    add("inf-origin", f.write(), "format", "position origin x is +Inf")
    f = edit()
    s = f.section(0x13)
    s[3] = s[3][:1] + b"\x00\x00\xc0\x7f" + s[3][5:]
    add("nan-step", f.write(), "format", "the opacity step is a NaN")
    f = edit()
    s = f.section(0x11)
    s[3] = replace_step(s[3], 0, 3e38)
    add("overflow", f.write(), "format",
        "scale step 3e38: the dequantised scales overflow to -Inf (§8)")
    f = edit()
    s = f.section(0x10)
    s[3] = s[3][:24] + bytes([22]) + s[3][25:]
    add("grid-bits", f.write(), "format", "position grid of 22 bits per axis")
    f = edit()
    s = f.section(0x13)
    s[3] = replace_table(s[3], 0, bytes([1]) + varint(zigzag(0)) + varint(4097) + b"\x01" * 4098)
    add("table-size", f.write(), "limits", "a coded table with n = 4097 symbols (4098 weights present)")
    f = edit()
    s = f.section(0x13)
    s[3] = replace_table(s[3], 0, bytes([4]) + varint(zigzag(0)))
    add("table-mode", f.write(), "format", "channel table mode 4")
    f = edit()
    s = f.section(0x13)
    s[3] = replace_table(s[3], 0, bytes([1]) + varint(zigzag(0x7FFFFFFF - 1)) + varint(2) + b"\x01\x01\x01")
    add("table-range", f.write(), "format", "lo + n = 2^31 overflows a signed 32-bit integer")
    f = edit()
    s = f.section(0x13)
    table = opa_params[0][1]
    weights = b"\x01" * table.n + b"\x80\x80\x80\x80\x10"
    s[3] = replace_table(s[3], 0, bytes([1]) + varint(zigzag(table.lo)) + varint(table.n) + weights)
    add("table-weight", f.write(), "format", "the escape weight is a varint of 2^32 (does not fit in 32 bits)")
    f = edit()
    s = f.section(0x10)
    weights = b"".join(varint(1) for _ in range(length_table.n + 1))
    s[3] = s[3][:25] + bytes([2]) + varint(0) + varint(zigzag(length_table.lo)) + varint(length_table.n) + weights * 4
    add("context-position", f.write(), "format", "the position length table has mode 2")

    # --- streams (§5, §6) ---
    rot_streams = streams_of(File(good).section(0x22)[3], 3)
    index_table = rot_params[0][1]
    index = decoded_values(rot_streams[0], index_table, k)
    f = edit()
    f.section(0x22)[3] = section_of([ans_encode(value_intervals(index_table, [4] + index[1:]))] + rot_streams[1:])
    add("escape-rotation", f.write(), "format", "the rotation index of Gaussian 0 is escaped to 4 (§6.2: 0..3)")

    (pos,) = streams_of(File(good).section(0x20)[3], 1)
    dec = specdec.AnsDecoder(pos, "positions")
    lengths, raws = [], []
    for _ in range(k):
        lengths.append(specdec.read_value(dec, length_table, [0]))
        raws.append(dec.raw_bits(lengths[-1] - 1) if lengths[-1] > 1 else 0)
    lengths[0], raws[0] = 3 * bits + 1, 0  # escaped: outside the table's range lo..lo+n
    intervals = []
    for length, r in zip(lengths, raws):
        intervals += value_intervals(length_table, [length])
        if length > 1:
            intervals += raw_intervals(r, length - 1)
    f = edit()
    f.section(0x20)[3] = section_of([ans_encode(intervals)])
    add("escape-length", f.write(), "format",
        f"Morton length of Gaussian 0 escaped to {3 * bits + 1} > 3 * bits (§6.1)")

    opa_table = opa_params[0][1]
    (opa_stream,) = streams_of(File(good).section(0x23)[3], 1)
    opa = decoded_values(opa_stream, opa_table, k)
    f = edit()
    f.section(0x23)[3] = section_of([ans_encode(value_intervals(opa_table, opa), start=1)])
    add("final-state", f.write(), "format",
        "the opacity stream decodes its 3 values and uses every word but ends in state 1, not 0")
    f = edit()
    # k symbols read at most 2 + k words: k + 3 words leave at least one unread.
    padded = opa_stream + b"\x01\x00\x00\x00" * (k + 3 - len(opa_stream) // 4)
    f.section(0x23)[3] = section_of([padded])
    add("leftover-words", f.write(), "format",
        "the opacity stream has more words than its 3 values can consume")
    f = edit()
    f.section(0x23)[3] = section_of([b"\x00\x00\x00\x00" + opa_stream])
    add("zero-word", f.write(), "format", "the opacity stream starts with a zero word")
    f = edit()
    f.section(0x23)[3] = section_of([opa_stream + b"\x00\x00"])
    add("stream-length", f.write(), "format", "the opacity stream is 2 bytes past a whole number of words")
    f = edit()
    f.section(0x23)[3] = section_of([opa_stream]) + b"\x00"
    add("section-tail", f.write(), "format", "one byte after the opacity section's last stream")
    return out


def make_levels(good, hand):
    """{name: (bytes, class, reason)}: the levels section (SPEC §3.1), from levels.gsc (4.0) and
    hand.gsc (3.0)."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    def levels_of(f):
        """The levels as a list of chunk-size lists."""
        rd = specdec.Reader(f.section(0x01)[3], "levels")
        return [[rd.varint() for _ in range(rd.varint())] for _ in range(rd.varint())]

    def with_levels(levels):
        f = File(good)
        f.section(0x01)[3] = varint(len(levels)) + b"".join(varint(len(l)) + b"".join(varint(k) for k in l) for l in levels)
        return f

    levels = levels_of(File(good))
    short = [l[:] for l in levels]
    short[-1][-1] -= 1
    add("levels-sum", with_levels(short).write(), "format", "the chunk sizes of the levels sum to N - 1")
    zero = [l[:] for l in levels]
    zero[-1].append(0)
    add("levels-zero", with_levels(zero).write(), "format", "the last level has an extra chunk of 0 Gaussians")
    big = [l[:] for l in levels]
    big[-1][-1] = 65537
    add("levels-big", with_levels(big).write(), "format", "a chunk of 65,537 Gaussians")
    empty = [l[:] for l in levels] + [[]]
    add("levels-empty", with_levels(empty).write(), "format", "a level of zero chunks")
    f = File(good)
    f.remove(0x01)
    add("levels-missing", f.write(), "format", "a 4.0 file with N > 0 without its levels section")
    f = File(good)
    last = len([k for l in levels for k in l])
    f.sections.append([0x23, last, 0, f.section(0x23, last - 1)[3], None])
    add("levels-beyond", f.write(), "format", f"an opacity data section of chunk {last}, beyond the {last} chunks of the levels")
    f = File(hand)
    f.sections.insert(0, [0x01, 0, 0, varint(1) + varint(1) + varint(f.n), None])
    add("levels-in-3", f.write(), "unsupported", "a 3.0 file with a levels section (kind 0x01, unknown in 3.0) without the optional bit")
    return out


def make_codebooks(good):
    """{name: (bytes, class, reason)}: the codebook sections (SPEC §3.2), from vq.gsc (5.0:
    N Gaussians, D = 2, band 1 by a codebook, band 2 per coefficient)."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    f0 = File(good)
    assert f0.major == 5 and f0.degree == 2
    book = f0.section(0x02, 1)[3]
    rd = specdec.Reader(book, "codebook")
    k = rd.varint()
    rest = book[rd.pos:]
    f = File(good)
    f.section(0x02, 1)[3] = varint(0) + rest
    add("codebook-rows-zero", f.write(), "format", "a codebook of 0 rows")
    f = File(good)
    f.section(0x02, 1)[3] = varint(f.n + 1) + rest
    add("codebook-rows-big", f.write(), "format", f"a codebook of N + 1 = {f.n + 1} rows (K <= N)")
    f = File(good)
    (table,) = [t for _, t in specdec.parse_group_params(5, f.section(0x15)[3], 1)]
    assert table.mode != 0
    (stream,) = streams_of(f.section(0x25)[3], 1)
    index = decoded_values(stream, table, f.n)
    f.section(0x25)[3] = section_of([ans_encode(value_intervals(table, [k] + index[1:]))])
    add("codebook-index", f.write(), "format", f"the band-1 row index of Gaussian 0 is escaped to K = {k}, past the codebook's last row")
    f = File(good)
    f.remove(0x02, 1)
    add("codebook-missing", f.write(), "format", "band 1's parameter section holds one index channel but its codebook section is absent")
    f = File(good)
    f.sections.append([0x02, 3, 0, book, None])
    add("codebook-band", f.write(), "format", "a codebook for SH band 3 in a file of SH degree 2")
    f = File(good)
    f.major = 4
    add("codebook-in-4", f.write(), "unsupported", "a 4.0 file with a codebook section (kind 0x02, unknown in 4.0) without the optional bit")
    return out


def make_classes(good):
    """{name: (bytes, class, reason)}: the parameter sections per level (SPEC §4), from
    classes.gsc (6.0: two levels, each with its own parameter sections)."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    f0 = File(good)
    assert f0.major == 6 and f0.section(0x11, 1)
    f = File(good)
    f.remove(0x11, 1)
    add("level-params-missing", f.write(), "format", "level 1's scale parameter section (0x11, chunk 1) is absent")
    f = File(good)
    f.sections.append([0x11, 2, 0, f.section(0x11, 1)[3], None])
    add("level-params-beyond", f.write(), "format", "a scale parameter section for level 2 in a file of two levels")
    f = File(good)
    f.major = 5
    add("level-params-in-5", f.write(), "unsupported", "a 5.0 file with parameter sections of chunk 1 (unknown in 5.0) without the optional bit")
    return out


def make_shared(good):
    """{name: (bytes, class, reason)}: the shared index (SPEC §3.2), from shared.gsc (9.0: D = 3,
    two levels, one codebook per band with bands 2 and 3 sharing band 1's index, no mode-3
    table)."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    f0 = File(good)
    assert f0.major == 9 and f0.degree == 3 and f0.section(0x16, 1)[3] == b"\x00"
    f = File(good)
    f.major = 8
    add("shared-in-8", f.write(), "format", "an 8.0 file whose band 2 parameter sections hold no channel (a shared index is 9.0 only)")
    f = File(good)
    f.section(0x15, 0)[3] = b"\x00"
    add("shared-band1", f.write(), "format", "band 1's parameter section of level 0 holds no channel (band 1 has no band below)")
    # Band 2's codebook with its last row dropped, its streams re-coded: K − 1 rows against band 1's K.
    f = File(good)
    book = f.section(0x02, 2)[3]
    rd = specdec.Reader(book, "codebook")
    k = rd.varint()
    start = rd.pos
    channels = specdec.read_group_channels(rd, 6, 15)
    params = book[start:rd.pos]
    rows = specdec.decode_channels(book[rd.pos:], k, channels, "codebook")
    assert all(t.mode in (0, 1, 2) for _, t in channels)
    streams = [ans_encode(value_intervals(t, [int(v) for v in rows[: k - 1, j]])) for j, (_, t) in enumerate(channels) if t.mode != 0]
    f.section(0x02, 2)[3] = varint(k - 1) + params + section_of(streams)
    add("shared-rows", f.write(), "format", f"band 2 shares band 1's index of K = {k} rows but its codebook has {k - 1}")
    # Level 1's band 2 with an index of its own (one constant channel: no stream), level 0's shared.
    f = File(good)
    f.section(0x16, 1)[3] = bytes([1]) + struct.pack("<f", 1.0) + bytes([0]) + varint(zigzag(0))
    add("shared-level", f.write(), "format", "band 2 shares band 1's index in level 0 but has an index of its own in level 1")
    f = File(good)
    f.sections.append([0x26, 0, 0, f.section(0x25, 0)[3], None])
    add("shared-stream", f.write(), "format", "a data section of band 2, which shares band 1's index, holds band 1's index stream")
    return out


def neighbour_table(reach, start, prev_at, lower_at, contexts):
    """§4.3: the bytes of a mode-3 table; contexts are (mix, centre, ratio)."""
    out = bytearray([3]) + varint(reach) + varint(zigzag(start))
    for at in (prev_at, lower_at):
        out += bytes([len(at)]) + b"".join(varint(zigzag(t)) for t in at)
    for mix, centre, ratio in contexts:
        out += bytes([mix]) + varint(zigzag(centre)) + bytes([ratio])
    return bytes(out)


def make_neighbour(good):
    """{name: (bytes, class, reason)}: the neighbour-context tables (SPEC §4.3), from
    neighbour.gsc (8.0), whose scale channel 0 (level 0) has a mode-3 table."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    f0 = File(good)
    assert f0.major == 8
    (_, t0) = specdec.parse_group_params(1, f0.section(0x11)[3], None, True)[0]
    assert t0.mode == 3 and not t0.lower_at
    ctx = [(mix, centre, 0) for mix, centre, _ in t0.contexts]
    f = File(good)
    f.major = 6
    add("neighbour-in-6", f.write(), "format", "a 6.0 file with mode-3 tables (the first met: in the sh_band1 codebook)")

    def with_table(table):
        f = File(good)
        s = f.section(0x11)
        s[3] = replace_table(s[3], 0, table)
        return f.write()

    lower = neighbour_table(t0.reach, t0.start, t0.prev_at, [0], ctx * 2)
    add("neighbour-lower-0", with_table(lower), "format", "scale channel 0's mode-3 table has a threshold on a channel below")
    add("neighbour-reach", with_table(neighbour_table(2048, t0.start, t0.prev_at, [], ctx)), "format", "a mode-3 table of reach E = 2048")
    bad_ratio = [(m, c, 64 if i == 0 else r) for i, (m, c, r) in enumerate(ctx)]
    add("neighbour-ratio", with_table(neighbour_table(t0.reach, t0.start, t0.prev_at, [], bad_ratio)), "format", "a mode-3 context of ratio index 64")
    bad_mix = [(5 if i == 0 else m, c, r) for i, (m, c, r) in enumerate(ctx)]
    add("neighbour-mix", with_table(neighbour_table(t0.reach, t0.start, t0.prev_at, [], bad_mix)), "format", "a mode-3 context of mix 5")
    many = list(range(16))
    add("neighbour-thresholds", with_table(neighbour_table(t0.reach, t0.start, many, [], [(0, 0, 0)] * 17)), "format", "a mode-3 table with 16 thresholds")
    # Start at 2^31 − 1, predict the previous value (mix 4) and code a difference of +1 first:
    # the value leaves i32 (§4.3). Every later value repeats its predecessor (difference 0).
    table = neighbour_table(1, 0x7FFFFFFF, [], [], [(4, 0, 0)])
    cdf = specdec.window_cdf(0, 1)
    f = File(good)
    s = f.section(0x11)
    s[3] = replace_table(s[3], 0, table)
    data = f.section(0x21)
    streams = streams_of(data[3], 3)
    n0 = level0_size(f0)
    symbols = [2] + [1] * (n0 - 1)
    streams[0] = ans_encode([(cdf[x], cdf[x + 1] - cdf[x]) for x in symbols])
    data[3] = section_of(streams)
    add("neighbour-overflow", f.write(), "format", "scale channel 0: a value predicted as 2^31 − 1 with a difference of +1 leaves i32")
    return out


def level0_size(f):
    """Gaussians of level 0 of a file with a levels section (§3.1)."""
    sizes, level_of = specdec.read_levels(f.section(0x01)[3], f.n)
    return sum(k for k, l in zip(sizes, level_of) if l == 0)


def anchor_layout(payload, n):
    """The parts of a valid anchor section (SPEC §12.1): a dict of its header fields and the
    byte offsets where each part ends (`layers`, `steps`, `weights`, `grid`, `positions`,
    `features`, end of section)."""
    rd = specdec.Reader(payload, "anchor")
    out = {"F": rd.u8(), "s": rd.u8()}
    layers = [(rd.varint(), rd.varint(), rd.u8()) for _ in range(rd.u8())]
    out["layer_list"], out["layers"] = layers, rd.pos
    rd.take(4 * layers[-1][1])
    out["steps"] = rd.pos
    for n_in, n_out, _ in layers:
        table = specdec.read_channel_table(rd, allow_context=False)
        specdec.decode_lengths(rd.take(rd.varint()), n_out * (n_in + 1), 25, table, "weights")
    out["weights"] = rd.pos
    _, _, out["bits"], table = specdec.read_grid(rd)
    out["grid"] = rd.pos
    _, codes = specdec.decode_position_stream(rd.take(rd.varint()), n, out["bits"], table, "positions")
    out["positions"] = rd.pos
    key = [int(m) >> (3 * out["s"]) for m in codes]
    out["A"] = 1 + sum(a != b for a, b in zip(key, key[1:]))
    specdec.read_block(rd, out["F"], out["A"], "features")
    out["features"] = rd.pos
    specdec.read_block(rd, 3, out["A"], "base")
    rd.expect_end()
    return out


def make_anchor(good, six):
    """{name: (bytes, class, reason)}: the anchor profile (SPEC §12), from anchor.gsc (7.0) and
    classes.gsc (6.0)."""
    out = {}

    def add(name, data, cls, reason):
        out[name] = (data, cls, reason)

    f0 = File(good)
    assert f0.major == 7 and f0.n > 0
    section = f0.section(0x03)[3]
    lay = anchor_layout(section, f0.n)
    f, layers = lay["F"], lay["layer_list"]

    def with_section(payload):
        g = File(good)
        g.section(0x03)[3] = payload
        return g.write()

    g = File(good)
    g.remove(0x03)
    # a padding section keeps N <= 8 * file length (§2), so only the missing section is wrong
    g.sections.append([0x101, 0, 1, bytes(len(section)), None])
    add("anchor-missing", g.write(), "format", "a 7.0 file with N > 0 without its anchor section (0x03, chunk 0)")
    g = File(six)
    assert g.major == 6
    g.sections.append([0x03, 0, 0, section, None])
    add("anchor-in-6", g.write(), "unsupported", "a 6.0 file with an anchor section (kind 0x03, unknown before 7.0) without the optional bit")
    features = section[lay["positions"]:lay["features"]]
    base = section[lay["features"]:]
    # s = bits + 1 (s >= bits puts every Gaussian in one anchor: the feature and base blocks
    # re-coded with anchor 0's row only, so that nothing but s is wrong)
    one = recode_block(features, lay["A"], lambda j, v: v[:1]) + recode_block(base, lay["A"], lambda j, v: v[:1])
    add("anchor-shift", with_section(bytes([f, lay["bits"] + 1]) + section[2:lay["positions"]] + one), "format",
        f"anchor shift s = {lay['bits'] + 1} above the grid's {lay['bits']} bits")
    # L = 0: no layer entries and no weight blocks; everything else as it was
    add("anchor-layers", with_section(bytes([f, lay["s"], 0]) + section[lay["layers"]:lay["steps"]] + section[lay["weights"]:]),
        "format", "an MLP of L = 0 layers (1 <= L <= 4)")
    # valid shapes F+3 -> 4096 -> 4096 -> P, each layer's weights a constant length table (0: every
    # weight 0) and an empty stream
    p = layers[-1][1]
    shapes = [(f + 3, 4096), (4096, 4096), (4096, p)]
    table = b"".join(varint(i) + varint(o) + b"\x00" for i, o in shapes)
    blocks = (bytes([0]) + varint(zigzag(0)) + varint(0)) * len(shapes)
    w = sum(o * (i + 1) for i, o in shapes)
    add("anchor-work", with_section(bytes([f, lay["s"], len(shapes)]) + table + section[lay["layers"]:lay["steps"]] + blocks + section[lay["weights"]:]),
        "limits", f"an MLP of layers {f + 3} -> 4096 -> 4096 -> {p}: W = {w} weights, above 2^18")
    # one feature of anchor 0 escaped to 2^24 (|v| < 2^24), its stream re-coded
    j, ftable = next((j, t) for j, (_, t) in enumerate(block_channels(features)) if t.mode != 0)
    assert not 0 <= (1 << 24) - ftable.lo < ftable.n  # outside the table's range: escaped
    add("anchor-feature", with_section(section[:lay["positions"]] + recode_block(features, lay["A"], lambda i, v: [1 << 24] + v[1:] if i == j else v) + base),
        "format", f"feature {j} of anchor 0 escaped to 2^24 (|v| < 2^24)")
    return out


def block_channels(block):
    """The (step bytes, table) of each channel of an anchor block (SPEC §12.1)."""
    rd = specdec.Reader(block, "block")
    return [(rd.take(4), specdec.read_channel_table(rd, allow_context=True)) for _ in range(rd.u8())]


def recode_block(block, rows, change):
    """An anchor block of `rows` rows (SPEC §12.1) with each coded channel j's values v
    replaced by change(j, v) and its stream re-coded (§5.4); constant channels stay."""
    rd = specdec.Reader(block, "block")
    for _ in range(rd.u8()):
        rd.take(4)
        specdec.read_channel_table(rd, allow_context=True)
    head = block[:rd.pos]
    streams = []
    for j, (_, table) in enumerate(block_channels(block)):
        if table.mode != 0:
            values = change(j, decoded_values(rd.take(rd.varint()), table, rows))
            streams.append(ans_encode(value_intervals(table, values)))
    rd.expect_end()
    return head + section_of(streams)


def make_quirks(good):
    """quirks.gsc: a valid file that uses what the SPEC allows and our encoder never writes, so
    a decoder MUST accept it and decode it to quirks.ply."""
    f, k = File(good), 3
    # Opacity (group 3): all-zero weights, i.e. the uniform table (§4.2), `lo` and the stream's
    # length as overlong varints (§1); its data section carries the optional bit (§3).
    params = f.section(0x13)
    table = specdec.parse_group_params(3, params[3])[0][1]
    values = decoded_values(streams_of(f.section(0x23)[3], 1)[0], table, k)
    params[3] = replace_table(params[3], 0, bytes([1]) + overlong(zigzag(table.lo)) + varint(table.n) + bytes(table.n + 1))
    table = specdec.parse_group_params(3, params[3])[0][1]
    stream = ans_encode(value_intervals(table, values))
    data = f.section(0x23)
    data[2], data[3] = 1, overlong(len(stream)) + stream
    # SH band 1 (group 5) channel 0: a context table (§4.1, §5.2) whose centre is -2^31, far
    # outside the values (the distance needs more than 32 bits), with four different weight lists.
    params, data = f.section(0x15), f.section(0x25)
    channels = specdec.parse_group_params(5, params[3])
    coded = [j for j, (_, t) in enumerate(channels) if t.mode != 0]
    streams = streams_of(data[3], len(coded))
    table = channels[0][1]
    values = decoded_values(streams[0], table, k)
    m = table.n + 1
    lists = [[1 + s for s in range(m)], [m - s for s in range(m)], [1] * m, [7 if s % 2 else 0 for s in range(m)]]
    weights = b"".join(varint(w) for ws in lists for w in ws)
    params[3] = replace_table(params[3], 0, bytes([2]) + varint(zigzag(-(1 << 31))) + varint(zigzag(table.lo)) + varint(table.n) + weights)
    table = specdec.parse_group_params(5, params[3])[0][1]
    data[3] = section_of([ans_encode(value_intervals(table, values))] + streams[1:])
    # Steps (§1): a subnormal scale step (subnormal results) and a -0.0 colour step (signed zeros).
    f.section(0x11)[3] = replace_step(f.section(0x11)[3], 0, 1e-40)
    f.section(0x14)[3] = replace_step(f.section(0x14)[3], 2, -0.0)
    # An unknown section with the optional bit (skipped, §2) and an info section of 3 bytes (§3).
    f.section(0x100)[3] = b"odd"
    f.sections.append([0x102, 0, 1, b"a later minor's section", None])
    return f.write()


def main(argv):
    """No argument: rewrite vectors/bad/ and its lines in SHA256SUMS. `--out DIR`: write the
    vectors and EXPECTED to DIR only (the test suite compares them with the committed ones)."""
    out_dir = argv[2] if len(argv) == 3 and argv[1] == "--out" else BAD
    good = open(os.path.join(VECTORS, "hand.gsc"), "rb").read()
    vectors = make(good)
    vectors.update(make_levels(open(os.path.join(VECTORS, "levels.gsc"), "rb").read(), good))
    vectors.update(make_codebooks(open(os.path.join(VECTORS, "vq.gsc"), "rb").read()))
    vectors.update(make_classes(open(os.path.join(VECTORS, "classes.gsc"), "rb").read()))
    vectors.update(make_anchor(open(os.path.join(VECTORS, "anchor.gsc"), "rb").read(), open(os.path.join(VECTORS, "classes.gsc"), "rb").read()))
    vectors.update(make_neighbour(open(os.path.join(VECTORS, "neighbour.gsc"), "rb").read()))
    vectors.update(make_shared(open(os.path.join(VECTORS, "shared.gsc"), "rb").read()))
    os.makedirs(out_dir, exist_ok=True)
    for old in os.listdir(out_dir):
        if old.startswith("bad-") and old.endswith(".gsc"):
            os.remove(os.path.join(out_dir, old))
    lines = ["# bad vector, expected error class (SPEC §9.1), reason; made by ../../make_bad_vectors.py from hand.gsc, levels.gsc, vq.gsc, classes.gsc, anchor.gsc, neighbour.gsc and shared.gsc"]
    for name, (data, cls, reason) in sorted(vectors.items()):
        with open(os.path.join(out_dir, f"bad-{name}.gsc"), "wb") as fh:
            fh.write(data)
        lines.append(f"bad-{name}.gsc {cls} {reason}")
    with open(os.path.join(out_dir, "EXPECTED"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    quirks = make_quirks(good)
    with open(os.path.join(out_dir if out_dir != BAD else VECTORS, "quirks.gsc"), "wb") as fh:
        fh.write(quirks)
    if out_dir == BAD:
        # quirks.ply is what specdec.py decodes quirks.gsc to (the Rust decoder is tested against it).
        n, degree, cols = specdec.decode(quirks)
        specdec.write_ply(os.path.join(VECTORS, "quirks.ply"), n, degree, cols)
        ply = open(os.path.join(VECTORS, "quirks.ply"), "rb").read()
        # SHA256SUMS: the encoder's vectors' lines (tests/vectors.rs `regenerate`), then ours.
        sums_path = os.path.join(VECTORS, "SHA256SUMS")
        kept = [l for l in open(sums_path).read().splitlines() if not l.endswith((".gsc", "quirks.ply"))]
        kept.append(f"{hashlib.sha256(ply).hexdigest()}  quirks.ply")
        for name, (data, _, _) in sorted(vectors.items()):
            kept.append(f"{hashlib.sha256(data).hexdigest()}  bad/bad-{name}.gsc")
        with open(sums_path, "w") as fh:
            fh.write("\n".join(kept) + "\n")
    print(f"wrote {len(vectors)} bad vectors to {out_dir}")


if __name__ == "__main__":
    main(sys.argv)
