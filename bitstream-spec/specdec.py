#!/usr/bin/env python3
"""Independent decoder for the gscodec `.gsc` bitstream, versions 3.x to 7.x (7.x: the
anchor profile of SPEC §12), written from bitstream-spec/SPEC.md alone (without reading the
Rust decoder), as a check that the spec is complete.  Usage: python3 specdec.py IN.gsc OUT.ply

Writes the reference .ply of SPEC §7.2.  For a file that breaks the SPEC: exit code 1,
no output file, and one line on stderr, `specdec: error: IN: CLASS: error: detail`, with
the error and its class as in SPEC §9.1.  Needs numpy.
"""
import struct
import sys
import zlib

import numpy as np

MAGIC = b"\x8aGSC"
VERSION_MAJORS = (3, 4, 5, 6, 7, 8, 9)  # §2, §11: 4.x adds the levels section (§3.1), 5.x codebooks (§3.2),
# 6.x parameter sections per level (§4), 7.x the anchor profile (§12), 8.x neighbour tables (§4.3),
# 9.x the shared index (§3.2)
ANCHOR_MAJOR = 7
NEIGHBOUR_MAJOR = 8
SHARED_MAJOR = 9
# §4.3: the window ratios r_ρ · 2^16, ρ = 0..63
RATIOS = [
    115, 283, 617, 1200, 2125, 3466, 5274, 7557, 10287, 13399, 16807, 20411, 24109, 27809, 31429, 34905,
    38190, 41250, 44069, 46637, 48958, 51039, 52894, 54537, 55986, 57259, 58374, 59346, 60193, 60928,
    61565, 62117, 62594, 63006, 63361, 63667, 63930, 64157, 64352, 64520, 64664, 64788, 64894, 64985,
    65064, 65131, 65189, 65238, 65280, 65317, 65348, 65375, 65398, 65418, 65434, 65449, 65461, 65472,
    65481, 65489, 65496, 65501, 65506, 65511,
]
MAX_REACH = 2047
MAX_THRESHOLDS = 15
MAX_SECTIONS = 4096
MAX_N = 1 << 26
MAX_TABLE_N = 4096
MAX_BITS = 21
CHUNK = 65536
PROB_BITS = 16
PROB_TOTAL = 1 << PROB_BITS

# group index -> channel count (position: its length table only)
GROUP_CHANNELS = [1, 3, 4, 1, 3, 9, 15, 21]
KIND_LEVELS = 0x01
KIND_CODEBOOK = 0x02
KIND_ANCHOR = 0x03
MAX_CODEBOOK_ROWS = 65536
KIND_INFO = 0x100
KIND_PADDING = 0x101


# SPEC §9.1: each error of the SPEC and its class.
CLASSES = {
    "bad magic": "format",
    "truncation": "format",
    "corrupt data": "format",
    "missing section": "format",
    "trailing data": "format",
    "checksum mismatch": "checksum",
    "unsupported major version": "unsupported",
    "unknown required section": "unsupported",
    "limit exceeded": "limits",
}


class DecodeError(Exception):
    """kind is one of the errors listed in SPEC §9.1; cls its class."""

    def __init__(self, kind, msg):
        self.kind = kind
        self.cls = CLASSES[kind]
        super().__init__(f"{self.cls}: {kind}: {msg}")


def corrupt(msg):
    return DecodeError("corrupt data", msg)


# ----------------------------------------------------------------------------
# Byte reader (§1)
# ----------------------------------------------------------------------------
class Reader:
    def __init__(self, data, what):
        self.data = data
        self.pos = 0
        self.what = what

    def remaining(self):
        return len(self.data) - self.pos

    def take(self, n):
        if n > self.remaining():
            raise DecodeError("truncation", f"{self.what}: need {n} bytes, {self.remaining()} left")
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b

    def u8(self):
        return self.take(1)[0]

    def u16(self):
        return struct.unpack("<H", self.take(2))[0]

    def u32(self):
        return struct.unpack("<I", self.take(4))[0]

    def f32(self):
        raw = self.take(4)
        v = np.frombuffer(raw, dtype="<f4")[0]
        if not np.isfinite(v):
            raise corrupt(f"{self.what}: non-finite f32 {raw.hex()}")
        return v  # np.float32

    def varint(self):
        value = 0
        for i in range(5):
            b = self.u8()
            value |= (b & 0x7F) << (7 * i)
            if not b & 0x80:
                if value >= 1 << 32:
                    raise corrupt(f"{self.what}: varint exceeds 32 bits")
                return value
        raise corrupt(f"{self.what}: varint longer than 5 bytes")

    def svarint(self):
        return unzigzag(self.varint())

    def expect_end(self):
        if self.remaining():
            raise corrupt(f"{self.what}: {self.remaining()} unconsumed bytes")


def unzigzag(z):
    return (z >> 1) ^ -(z & 1)


# ----------------------------------------------------------------------------
# Tables (§4.1, §4.2)
# ----------------------------------------------------------------------------
def build_cdf(weights):
    m = len(weights)
    w = list(weights)
    if all(x == 0 for x in w):
        w = [1] * m
    total = sum(w)
    r = PROB_TOTAL - m
    f = [1 + (x * r) // total for x in w]
    biggest = max(w)
    b = w.index(biggest)  # smallest index with the largest weight
    f[b] += PROB_TOTAL - sum(f)
    cdf = [0]
    for x in f:
        cdf.append(cdf[-1] + x)
    assert cdf[-1] == PROB_TOTAL and min(f) >= 1
    return cdf


class ChannelTable:
    def __init__(self, mode, value=0, lo=0, n=0, centre=0, cdfs=()):
        self.mode = mode      # 0 constant, 1 coded, 2 context, 3 neighbour (fields set by read_neighbour)
        self.value = value
        self.lo = lo
        self.n = n
        self.centre = centre
        self.cdfs = list(cdfs)  # one cdf (mode 1) or four (mode 2)


def read_weights(rd, m):
    # every weight is at least one byte: check before allocating
    if m > rd.remaining():
        raise DecodeError("truncation", f"{rd.what}: {m} weights cannot fit")
    return [rd.varint() for _ in range(m)]


def read_lo_n(rd):
    lo = rd.svarint()
    n = rd.varint()
    if not 1 <= n <= MAX_TABLE_N:
        raise DecodeError("limit exceeded", f"{rd.what}: table size n={n}")
    if lo + n > 0x7FFFFFFF:
        raise corrupt(f"{rd.what}: lo + n overflows i32")
    return lo, n


def window_cdf(ratio, reach):
    """§4.3: the window of ratio index `ratio` and reach E over 2E + 2 symbols."""
    w = [0] * (2 * reach + 2)
    x = 1 << 30
    for d in range(reach + 1):
        w[reach + d] = w[reach - d] = x
        x = (x * RATIOS[ratio]) >> 16
    return build_cdf(w)


def read_neighbour(rd):
    """§4.3: a mode-3 table after its mode byte."""
    t = ChannelTable(3)
    t.reach = rd.varint()
    if not 1 <= t.reach <= MAX_REACH:
        raise corrupt(f"{rd.what}: window reach {t.reach}")
    t.start = rd.svarint()
    ats = []
    for _ in range(2):
        k = rd.u8()
        if k > MAX_THRESHOLDS:
            raise corrupt(f"{rd.what}: {k} thresholds")
        ats.append([rd.svarint() for _ in range(k)])
    t.prev_at, t.lower_at = ats
    count = (len(t.prev_at) + 1) * (len(t.lower_at) + 1)
    if 3 * count > rd.remaining():
        raise DecodeError("truncation", f"{rd.what}: {count} contexts cannot fit")
    t.contexts = []
    cdfs = {}
    for _ in range(count):
        mix, centre, ratio = rd.u8(), rd.svarint(), rd.u8()
        if mix > 4 or ratio > 63:
            raise corrupt(f"{rd.what}: context mix {mix} or ratio {ratio}")
        if ratio not in cdfs:
            cdfs[ratio] = window_cdf(ratio, t.reach)
        t.contexts.append((mix, centre, cdfs[ratio]))
    return t


def read_channel_table(rd, allow_context, allow_neighbour=False):
    mode = rd.u8()
    if mode == 0:
        return ChannelTable(0, value=rd.svarint())
    if mode == 1:
        lo, n = read_lo_n(rd)
        return ChannelTable(1, lo=lo, n=n, cdfs=[build_cdf(read_weights(rd, n + 1))])
    if mode == 2 and allow_context:
        centre = rd.svarint()
        lo, n = read_lo_n(rd)
        cdfs = [build_cdf(read_weights(rd, n + 1)) for _ in range(4)]
        return ChannelTable(2, lo=lo, n=n, centre=centre, cdfs=cdfs)
    if mode == 3 and allow_neighbour:
        return read_neighbour(rd)
    raise corrupt(f"{rd.what}: bad table mode {mode}")


# ----------------------------------------------------------------------------
# Entropy decoder (§5: init and decode step; §5.1 raw bits; §5.3 end check)
# ----------------------------------------------------------------------------
class AnsDecoder:
    def __init__(self, data, what):
        if len(data) % 4:
            raise corrupt(f"{what}: stream length {len(data)} not a multiple of 4")
        self.words = struct.unpack(f"<{len(data) // 4}I", data)
        self.what = what
        self.next = 0
        if not self.words:
            self.x = 0
        else:
            if self.words[0] == 0:
                raise corrupt(f"{what}: first word is zero")
            self.x = self.words[0]
            self.next = 1
            if len(self.words) > 1:
                self.x = (self.x << 32) | self.words[1]
                self.next = 2

    def _advance(self, start, freq, q):
        self.x = (self.x >> 16) * freq + (q - start)
        if self.x < (1 << 32) and self.next < len(self.words):
            self.x = (self.x << 32) | self.words[self.next]
            self.next += 1

    def symbol(self, cdf):
        q = self.x & 0xFFFF
        # binary search: largest s with cdf[s] <= q
        lo, hi = 0, len(cdf) - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if cdf[mid] <= q:
                lo = mid
            else:
                hi = mid
        self._advance(cdf[lo], cdf[lo + 1] - cdf[lo], q)
        return lo

    def raw(self, k):
        # §5.1: uniform table over 2^k symbols, f = 2^(16-k)
        assert 1 <= k <= 16
        shift = 16 - k
        q = self.x & 0xFFFF
        s = q >> shift
        self._advance(s << shift, 1 << shift, q)
        return s

    def raw_bits(self, bits):
        left, value = bits, 0
        while left > 0:
            take = min(left, 16)
            left -= take
            value = (value << take) | self.raw(take)
        return value

    def finish(self):
        if self.next != len(self.words) or self.x != 0:
            raise corrupt(f"{self.what}: end check failed "
                          f"({len(self.words) - self.next} words left, x={self.x:#x})")


def table_for(table, prev):
    """§5.2: the cdf a coded or context table uses for a value whose predecessor is `prev`."""
    if table.mode == 1:
        return table.cdfs[0]
    d = abs(prev - table.centre)  # Python integers: no overflow
    return table.cdfs[0 if d == 0 else 1 if d == 1 else 2 if d <= 3 else 3]


def read_neighbour_value(dec, t, prev, lower):
    """§4.3: one value of a mode-3 channel after `prev`, with `lower` below it."""
    bp = sum(1 for x in t.prev_at if prev >= x)
    bl = sum(1 for x in t.lower_at if lower >= x)
    mix, centre, cdf = t.contexts[bp * (len(t.lower_at) + 1) + bl]
    mu = (mix * prev + (4 - mix) * centre + 2) >> 2  # Python integers: floor, no overflow
    s = dec.symbol(cdf)
    if s == 2 * t.reach + 1:
        return unzigzag(dec.raw_bits(32))
    v = mu + s - t.reach
    if not -(1 << 31) <= v < (1 << 31):
        raise corrupt(f"{dec.what}: predicted value {v} outside i32")
    return v


def read_value(dec, table, state):
    """§5.2. state is a one-element list holding `prev`, set to `centre` when the stream starts."""
    if table.mode == 0:
        return table.value
    s = dec.symbol(table_for(table, state[0]))
    v = table.lo + s if s < table.n else unzigzag(dec.raw_bits(32))
    state[0] = v
    return v


# ----------------------------------------------------------------------------
# Container (§2, §3)
# ----------------------------------------------------------------------------
def parse_container(data):
    if len(data) < 4 or data[:4] != MAGIC:
        raise DecodeError("bad magic", "not a .gsc file")
    rd = Reader(data, "header")
    rd.take(4)
    major, minor = rd.u8(), rd.u8()
    if major not in VERSION_MAJORS:
        raise DecodeError("unsupported major version", f"{major}.{minor}")
    s_count = rd.u16()
    n = rd.u32()
    degree = rd.u8()
    flags = rd.u8()
    reserved = rd.u16()
    if s_count > MAX_SECTIONS:
        raise DecodeError("limit exceeded", f"S={s_count}")
    if n > MAX_N or n > 8 * len(data):
        raise DecodeError("limit exceeded", f"N={n} (file length {len(data)})")
    if degree > 3:
        raise corrupt(f"SH degree {degree}")
    if flags != 0 or reserved != 0:
        raise corrupt("header flags/reserved not zero")
    table = []
    for _ in range(s_count):
        table.append(struct.unpack("<HHIII", rd.take(16)))
    header_crc = rd.u32()
    if zlib.crc32(data[:rd.pos - 4]) != header_crc:
        raise DecodeError("checksum mismatch", "header CRC")

    sections = {}
    for kind, chunk, sflags, length, crc in table:
        rd.what = f"section {kind:#x}/{chunk}"
        payload = rd.take(length)
        if zlib.crc32(payload) != crc:
            raise DecodeError("checksum mismatch", f"section {kind:#x}/{chunk}")
        if sflags & ~1:
            raise corrupt(f"section {kind:#x}/{chunk}: flags {sflags:#x}")
        if (kind, chunk) in sections:
            raise corrupt(f"duplicate section {kind:#x}/{chunk}")
        sections[(kind, chunk)] = (sflags, payload)
    if rd.remaining():
        raise DecodeError("trailing data", f"{rd.remaining()} bytes after last payload")
    return major, n, degree, sections


def read_levels(payload, n):
    """§3.1: the levels section; returns the chunk sizes in file order and each chunk's level."""
    rd = Reader(payload, "levels")
    sizes = []
    level_of = []
    for level in range(rd.varint()):
        c = rd.varint()
        if c == 0:
            raise corrupt("level of zero chunks")
        for _ in range(c):
            k = rd.varint()
            if not 1 <= k <= CHUNK:
                raise corrupt(f"chunk size {k}")
            sizes.append(k)
            level_of.append(level)
    rd.expect_end()
    if len(sizes) > CHUNK:
        raise corrupt(f"{len(sizes)} chunks")
    if sum(sizes) != n:
        raise corrupt(f"chunk sizes sum to {sum(sizes)}, N = {n}")
    return sizes, level_of


def classify_sections(major, n, degree, sections):
    """Check known/unknown sections; return {(kind, chunk): payload} for known ones, the
    chunk sizes and, per chunk, the chunk of the parameter sections it uses (§3, §3.1, §4)."""
    groups = (5 + degree) if n > 0 else 0
    levels = major >= 4
    codebooks = major >= 5
    level_params = major >= 6
    chunks = (n + CHUNK - 1) // CHUNK
    known = {}
    if major == ANCHOR_MAJOR:
        # §3: a 7.0 file knows the anchor section (when N > 0), info and padding; nothing else.
        for (kind, chunk), (sflags, payload) in sections.items():
            if (kind == KIND_ANCHOR and chunk == 0 and n > 0) or (kind in (KIND_INFO, KIND_PADDING) and chunk == 0):
                known[(kind, chunk)] = payload
            elif not sflags & 1:
                raise DecodeError("unknown required section", f"{kind:#x}/{chunk}")
        if n > 0 and (KIND_ANCHOR, 0) not in known:
            raise DecodeError("missing section", "anchor")
        return known, 0, [], []
    for (kind, chunk), (sflags, payload) in sections.items():
        is_known = (
            (0x10 <= kind < 0x10 + groups and (chunk == 0 or level_params))
            or (0x20 <= kind < 0x20 + groups and (levels or chunk < chunks))
            or (kind in (KIND_INFO, KIND_PADDING) and chunk == 0)
            or (levels and n > 0 and kind == KIND_LEVELS and chunk == 0)
            or (codebooks and n > 0 and kind == KIND_CODEBOOK and 1 <= chunk <= 3)
        )
        if is_known:
            known[(kind, chunk)] = payload
        elif not sflags & 1:
            raise DecodeError("unknown required section", f"{kind:#x}/{chunk}")
    if levels and n > 0:
        if (KIND_LEVELS, 0) not in known:
            raise DecodeError("missing section", "levels")
        sizes, level_of = read_levels(known[(KIND_LEVELS, 0)], n)
        nlevels = level_of[-1] + 1
        for kind, chunk in known:
            if 0x20 <= kind < 0x28 and chunk >= len(sizes):
                raise corrupt(f"data section {kind:#x}/{chunk} beyond the {len(sizes)} chunks of the levels")
            if 0x10 <= kind < 0x18 and chunk >= nlevels:
                raise corrupt(f"parameter section {kind:#x}/{chunk} beyond the {nlevels} levels")
    else:
        sizes = [min(n, CHUNK * (c + 1)) - CHUNK * c for c in range(chunks)]
        level_of = [0] * len(sizes)
    # §4: before 6.0 every chunk uses the parameter sections of chunk 0; in 6.0 those of its level.
    params_of = level_of if level_params else [0] * len(sizes)
    for g in range(groups):
        for p in sorted(set(params_of)) or [0]:
            if (0x10 + g, p) not in known:
                raise DecodeError("missing section", f"parameters of group {g}, chunk {p}")
    for kind, chunk in known:
        if kind == KIND_CODEBOOK and chunk > degree:
            raise corrupt(f"codebook of SH band {chunk} in a file of degree {degree}")
    # The info section is informative (§3): its content is never a reason to reject a file.
    return known, groups, sizes, params_of


# ----------------------------------------------------------------------------
# Parameters (§4) and data sections (§6)
# ----------------------------------------------------------------------------
def parse_position_params(payload):
    rd = Reader(payload, "position parameters")
    grid = read_grid(rd)
    rd.expect_end()
    return grid


def read_grid(rd):
    """§4, g = 0: origin, step, bits and the Morton length table."""
    origin = [rd.f32() for _ in range(3)]
    step = [rd.f32() for _ in range(3)]
    bits = rd.u8()
    if bits > MAX_BITS:
        raise corrupt(f"{rd.what}: grid bits {bits}")
    table = read_channel_table(rd, allow_context=False)
    return origin, step, bits, table


def read_group_channels(rd, g, expected, neighbours=False):
    """§4; `neighbours`: mode 3 is allowed (an 8.0 file, §4.3), never with thresholds on the
    channel below for channel 0."""
    c = rd.u8()
    if c not in (expected if isinstance(expected, tuple) else (expected,)):
        raise corrupt(f"group {g}: channel count {c}, expected {expected}")
    channels = []
    for j in range(c):
        step = rd.f32()
        table = read_channel_table(rd, allow_context=True, allow_neighbour=neighbours)
        if table.mode == 3 and j == 0 and table.lower_at:
            raise corrupt(f"group {g}: channel 0 has thresholds on a channel below")
        channels.append((step, table))
    return channels


def parse_group_params(g, payload, expected=None, neighbours=False):
    """§4; `expected` = 1 for an SH band with a codebook (§3.2: the index channel), (0, 1) for
    one that may share the index of the band below (9.0); a tuple lists the counts allowed."""
    rd = Reader(payload, f"parameters of group {g}")
    channels = read_group_channels(rd, g, GROUP_CHANNELS[g] if expected is None else expected, neighbours)
    rd.expect_end()
    return channels


def parse_codebook(g, payload, n, neighbours=False):
    """§3.2: (channels [(step, table)], K × C integer rows)."""
    rd = Reader(payload, f"codebook of group {g}")
    k = rd.varint()
    if not 1 <= k <= min(n, MAX_CODEBOOK_ROWS):
        raise corrupt(f"codebook of {k} rows (N = {n})")
    channels = read_group_channels(rd, g, GROUP_CHANNELS[g], neighbours)
    rows = decode_channels(rd.take(rd.remaining()), k, channels, f"codebook of group {g}")
    return channels, rows


def split_streams(payload, count, what):
    rd = Reader(payload, what)
    streams = []
    for j in range(count):
        length = rd.varint()
        streams.append(rd.take(length))
    rd.expect_end()
    return streams


def decode_positions(payload, k, bits, table, what):
    (stream,) = split_streams(payload, 1, what)
    return decode_position_stream(stream, k, bits, table, what)[0]


def decode_lengths(stream, k, max_len, table, what):
    """§6.1's code: k values, each a length L (at most max_len) from `table`, then L − 1 raw
    bits below the leading one; the stream's end is checked (§5.3)."""
    dec = AnsDecoder(stream, what)
    state = [0]
    values = []
    for _ in range(k):
        length = read_value(dec, table, state)
        if not 0 <= length <= max_len:
            raise corrupt(f"{what}: length {length}")
        values.append(length if length <= 1 else (1 << (length - 1)) + dec.raw_bits(length - 1))
    dec.finish()
    return values


def decode_position_stream(stream, k, bits, table, what):
    """§6.1: the grid coordinates q (k × 3) and the Morton codes of one position stream."""
    limit = 1 << (3 * bits)
    m = 0
    codes = np.empty(k, dtype=np.uint64)
    for i, d in enumerate(decode_lengths(stream, k, 3 * bits, table, what)):
        m += d
        if m >= limit:
            raise corrupt(f"{what}: Morton code out of range")
        codes[i] = m
    q = np.zeros((k, 3), dtype=np.int64)
    for bit in range(bits):
        for axis in range(3):
            q[:, axis] |= ((codes >> np.uint64(3 * bit + axis)) & np.uint64(1)).astype(np.int64) << bit
    return q, codes


def decode_channels(payload, k, channels, what):
    coded = [j for j, (_, t) in enumerate(channels) if t.mode != 0]
    streams = split_streams(payload, len(coded), what)
    values = np.empty((k, len(channels)), dtype=np.int64)
    for j, (_, table) in enumerate(channels):
        if table.mode == 0:
            values[:, j] = table.value
    for j, stream in zip(coded, streams):  # in channel order: channel j − 1 is known (§4.3)
        table = channels[j][1]
        dec = AnsDecoder(stream, f"{what} channel {j}")
        if table.mode == 3:
            col, prev = [], table.start
            for i in range(k):
                prev = read_neighbour_value(dec, table, prev, int(values[i, j - 1]) if j > 0 else 0)
                col.append(prev)
        else:
            state = [table.centre]
            col = [read_value(dec, table, state) for _ in range(k)]
        dec.finish()
        values[:, j] = col
    return values


# ----------------------------------------------------------------------------
# The anchor profile (§12)
# ----------------------------------------------------------------------------
MAX_ANCHOR_LAYERS = 4
MAX_ANCHOR_WIDTH = 4096
MAX_ANCHOR_SHIFT = 62
MAX_ANCHOR_WEIGHTS = 1 << 18   # W (§12.1, limits)
MAX_ANCHOR_WORK = 1 << 34      # N · W (§12.1, limits)
ANCHOR_BOUND = 1 << 24         # |weight|, |feature| < 2^24; MLP values clamped to ±(2^24 − 1)
MLP_ROWS = 4096                # Gaussians per MLP batch (any batching gives the same integers)


def read_block(rd, channels, rows, what):
    """§12.1: a block of `channels` channels and `rows` rows; returns (steps, rows × channels
    int64 values, row r's channel j at [r, j])."""
    c = rd.u8()
    if c != channels:
        raise corrupt(f"{what}: {c} channels, expected {channels}")
    tables = [(rd.f32(), read_channel_table(rd, allow_context=True)) for _ in range(c)]
    values = np.empty((rows, c), dtype=np.int64)
    for j, (_, table) in enumerate(tables):
        if table.mode == 0:
            values[:, j] = table.value
            continue
        stream = rd.take(rd.varint())
        dec = AnsDecoder(stream, f"{what} channel {j}")
        state = [table.centre]  # §5.2: every stream has its own context state
        values[:, j] = [read_value(dec, table, state) for _ in range(rows)]
        dec.finish()
    return [step for step, _ in tables], values


def check_bounded(values, what):
    """§12.1: every weight and feature, escaped ones too, has |v| < 2^24."""
    if values.size and int(np.abs(values).max()) >= ANCHOR_BOUND:
        raise corrupt(f"{what}: a value of magnitude 2^24 or more")


def run_mlp(x, layers, weights):
    """§12.2 on the rows of x (int64, one row per Gaussian): signed 64-bit integers, an
    arithmetic (floor) shift, a clamp to ±(2^24 − 1), ReLU on every layer but the last."""
    for l, ((n_in, _, shift), w) in enumerate(zip(layers, weights)):
        # exact: |w|, |x| < 2^24 and n_in ≤ 4096, so |acc| < 2^61 (numpy integer matmul does
        # no floating point)
        acc = x @ w[:, :n_in].T + w[:, n_in]
        y = np.clip(acc >> np.int64(shift), -(ANCHOR_BOUND - 1), ANCHOR_BOUND - 1)
        if l < len(layers) - 1:
            y = np.maximum(y, 0)
        x = y
    return x


def decode_anchor(payload, n, degree):
    """§12: the anchor section of a 7.0 file with N > 0; returns the output columns."""
    rd = Reader(payload, "anchor section")
    f = rd.u8()
    if f == 0:
        raise corrupt("anchor section: F = 0")
    s = rd.u8()
    nl = rd.u8()
    if not 1 <= nl <= MAX_ANCHOR_LAYERS:
        raise corrupt(f"anchor section: {nl} MLP layers")
    p = 8 + 3 * (degree + 1) ** 2
    layers = []
    for l in range(nl):
        n_in, n_out, shift = rd.varint(), rd.varint(), rd.u8()
        if n_in != (f + 3 if l == 0 else layers[-1][1]):
            raise corrupt(f"anchor section: layer {l} has {n_in} inputs")
        if not 1 <= n_out <= MAX_ANCHOR_WIDTH:
            raise corrupt(f"anchor section: layer {l} has {n_out} outputs")
        if shift > MAX_ANCHOR_SHIFT:
            raise corrupt(f"anchor section: layer {l} shift {shift}")
        layers.append((n_in, n_out, shift))
    if layers[-1][1] != p:
        raise corrupt(f"anchor section: the last layer has {layers[-1][1]} outputs, P = {p}")
    w_count = sum(n_out * (n_in + 1) for n_in, n_out, _ in layers)
    # §12.1: checked before any block is read
    if w_count > MAX_ANCHOR_WEIGHTS or n * w_count > MAX_ANCHOR_WORK:
        raise DecodeError("limit exceeded", f"anchor MLP of {w_count} weights for N = {n}")
    out_steps = np.array([rd.f32() for _ in range(p)], dtype=np.float32)
    weights = []
    for l, (n_in, n_out, _) in enumerate(layers):
        # §12.1: a length table (not mode 2), then one stream of zigzag values in §6.1's code
        table = read_channel_table(rd, allow_context=False)
        stream = rd.take(rd.varint())
        z = decode_lengths(stream, n_out * (n_in + 1), 25, table, f"anchor layer {l} weights")
        w = np.array([unzigzag(v) for v in z], dtype=np.int64)
        check_bounded(w, f"anchor layer {l} weights")
        weights.append(w.reshape(n_out, n_in + 1))  # row j: w_(j,0) … w_(j,in−1), then b_j
    rd.what = "anchor grid"
    origin, step, bits, length_table = read_grid(rd)
    if s > bits:
        raise corrupt(f"anchor section: anchor shift {s} above the grid's {bits} bits")
    rd.what = "anchor section"
    stream = rd.take(rd.varint())
    q, codes = decode_position_stream(stream, n, bits, length_table, "anchor positions")
    # Anchors: consecutive Gaussians with the same m >> 3s (s ≤ bits ≤ 21, so 3s ≤ 63).
    key = codes >> np.uint64(3 * s)
    anchor_of = np.concatenate([[0], np.cumsum(key[1:] != key[:-1])]).astype(np.int64)
    a_count = int(anchor_of[-1]) + 1
    _, features = read_block(rd, f, a_count, "anchor features")
    check_bounded(features, "anchor features")
    base_steps, base_ints = read_block(rd, 3, a_count, "anchor base scales")
    rd.expect_end()

    # §12.2: the MLP, in batches of Gaussians.
    cells = q & ((1 << s) - 1)
    outs = []
    for start in range(0, n, MLP_ROWS):
        rows = slice(start, min(n, start + MLP_ROWS))
        x = np.concatenate([features[anchor_of[rows]], cells[rows]], axis=1)
        outs.append(run_mlp(x, layers, weights))
    o = np.concatenate(outs)

    # §12.3, §8: binary32, each operation rounded (numpy float32 arrays, no fused multiply-add).
    with np.errstate(all="ignore"):
        pos = (np.asarray(origin, np.float32) + (q.astype(np.float32) * np.asarray(step, np.float32))).astype(np.float32)
        vals = o.astype(np.float32) * out_steps  # exact f32(o): |o| < 2^24
        base = base_ints.astype(np.float32) * np.asarray(base_steps, np.float32)
        scale = vals[:, 1:4] + base[anchor_of]
    check_finite(pos, "position")
    check_finite(base, "anchor base scale")
    check_finite(vals, "anchor output")
    check_finite(scale, "scale")
    rot = vals[:, 4:8].copy()
    rot[np.all(rot == 0, axis=1)] = np.array([1, 0, 0, 0], np.float32)  # +0 and −0 alike
    ncoef = (degree + 1) ** 2 - 1
    # output 11 + 3m + c is coefficient m of colour c; §7.2 stores f_rest colour-major
    rest = vals[:, 11:].reshape(n, ncoef, 3).transpose(0, 2, 1).reshape(n, 3 * ncoef)
    return {"pos": pos, "scale": scale, "rot": rot, "opacity": vals[:, 0:1], "dc": vals[:, 8:11], "rest": rest}


# ----------------------------------------------------------------------------
# Dequantisation (§8)
# ----------------------------------------------------------------------------
def dequant(values, steps):
    out = values.astype(np.float32) * np.asarray(steps, dtype=np.float32)
    return out.astype(np.float32)


def check_finite(arr, what):
    if not np.all(np.isfinite(arr)):
        raise corrupt(f"non-finite dequantised {what}")


def decode(data):
    major, n, degree, sections = parse_container(data)
    known, groups, sizes, params_of = classify_sections(major, n, degree, sections)

    cols = {}
    if major == ANCHOR_MAJOR:
        if n > 0:
            cols = decode_anchor(known[(KIND_ANCHOR, 0)], n, degree)
    elif n > 0:
        nb = major in (NEIGHBOUR_MAJOR, SHARED_MAJOR)
        books = {g: parse_codebook(g, known[(KIND_CODEBOOK, g - 4)], n, nb) for g in range(5, groups) if (KIND_CODEBOOK, g - 4) in known}

        def index_channels(g):
            # §3.2: a codebook band's one index channel; in 9.0 a band above 1 may have none.
            if g not in books:
                return None
            return (0, 1) if major == SHARED_MAJOR and g >= 6 else 1

        # §4: one set of parameter sections per parameter chunk (per level in 6.0, else chunk 0).
        params = {}
        for p in sorted(set(params_of)):
            position = parse_position_params(known[(0x10, p)])
            params[p] = (position, {g: parse_group_params(g, known[(0x10 + g, p)], index_channels(g), nb) for g in range(1, groups)})
        # §3.2 (9.0): a band whose parameter sections hold no channel shares the row index of the
        # band below: in every level, and the band below has a codebook of as many rows.
        shares = {}
        for g in books:
            counts = {len(params[p][1][g]) for p in params}
            if 0 in counts:
                if counts != {0}:
                    raise corrupt(f"group {g}: shares the index of the band below in some levels only")
                if g - 1 not in books or len(books[g - 1][1]) != len(books[g][1]):
                    raise corrupt(f"group {g}: shares the index of a band below without a codebook of as many rows")
                shares[g] = True

        def index_source(g):
            while shares.get(g):
                g -= 1
            return g
        ints = {g: [] for g in range(groups)}
        for c, k in enumerate(sizes):
            (_, _, bits, ltable), group_params = params[params_of[c]]
            for g in range(groups):
                payload = known.get((0x20 + g, c), b"")
                what = f"data group {g} chunk {c}"
                if g == 0:
                    ints[0].append(decode_positions(payload, k, bits, ltable, what))
                else:
                    ints[g].append(decode_channels(payload, k, group_params[g], what))

        with np.errstate(all="ignore"):
            # §8, chunk by chunk with the steps of the chunk's parameter sections.
            pos_parts, deq_parts = [], {g: [] for g in range(1, groups)}
            for c in range(len(sizes)):
                (origin, pstep, _, _), group_params = params[params_of[c]]
                p = np.asarray(origin, np.float32) + (ints[0][c].astype(np.float32) * np.asarray(pstep, np.float32))
                pos_parts.append(p.astype(np.float32))
                for g in range(1, groups):
                    steps = [s for s, _ in group_params[g]]
                    v = ints[g][c]
                    if g == 2:
                        idx = v[:, 0]
                        if np.any((idx < 0) | (idx > 3)):
                            raise corrupt("rotation index out of 0..3")
                        deq_parts[g].append(dequant(v[:, 1:], steps[1:]))
                    elif g in books:
                        # §3.2, §8: row index i of the band's codebook, dequantised with its steps
                        # (the index of the band below when the band shares it).
                        bchannels, rows = books[g]
                        book = dequant(rows, [s for s, _ in bchannels])
                        check_finite(book, f"codebook of group {g}")
                        idx = ints[index_source(g)][c][:, 0]
                        if np.any((idx < 0) | (idx >= len(rows))):
                            raise corrupt(f"group {g}: codebook index out of range")
                        deq_parts[g].append(book[idx])
                    else:
                        deq_parts[g].append(dequant(v, steps))
            pos = np.concatenate(pos_parts)
            check_finite(pos, "position")
            deq = {g: np.concatenate(v) for g, v in deq_parts.items()}
            for g in range(1, groups):
                check_finite(deq[g], f"group {g}")
            ints[2] = np.concatenate(ints[2])
            c0, c1, c2 = (deq[2][:, i] for i in range(3))
            t = (c0 * c0 + c1 * c1) + c2 * c2
            big = np.sqrt(np.maximum(np.float32(1) - t, np.float32(0))).astype(np.float32)
            # big goes to slot i; c0, c1, c2 fill the other slots in increasing order
            idx = ints[2][:, 0]
            rot = np.empty((n, 4), np.float32)
            for slot in range(4):
                # the stored component that lands in `slot` is c[slot] if slot < i else c[slot-1]
                below = [c0, c1, c2, c2][slot]
                above = [c0, c0, c1, c2][slot]
                rot[:, slot] = np.where(idx == slot, big, np.where(slot < idx, below, above))
            check_finite(rot, "rotation")

        cols["pos"] = pos
        cols["scale"] = deq[1]
        cols["rot"] = rot
        cols["opacity"] = deq[3]
        cols["dc"] = deq[4]
        # §7: band b's coefficients m go to rest coefficients b²-1+m; §7.2: each
        # colour's coefficients are stored contiguously (INRIA f_rest layout).
        ncoef = (degree + 1) ** 2 - 1
        rest = np.zeros((n, 3, ncoef), np.float32)
        for b in range(1, degree + 1):
            vals = deq[4 + b]  # channel j = 3*m + colour
            for m_ in range(2 * b + 1):
                for colour in range(3):
                    rest[:, colour, b * b - 1 + m_] = vals[:, 3 * m_ + colour]
        cols["rest"] = rest.reshape(n, 3 * ncoef)
    return n, degree, cols


# ----------------------------------------------------------------------------
# PLY output (§7.2)
# ----------------------------------------------------------------------------
def write_ply(path, n, degree, cols):
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    nrest = 3 * ((degree + 1) ** 2 - 1)
    names += [f"f_rest_{i}" for i in range(nrest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element vertex {n}\n"
    header += "".join(f"property float {name}\n" for name in names)
    header += "end_header\n"
    if n:
        body = np.concatenate([
            cols["pos"], np.zeros((n, 3), np.float32), cols["dc"], cols["rest"],
            cols["opacity"], cols["scale"], cols["rot"],
        ], axis=1).astype("<f4")
        assert body.shape[1] == len(names)
        body_bytes = body.tobytes()
    else:
        body_bytes = b""
    with open(path, "wb") as f:
        f.write(header.encode("ascii") + body_bytes)


def main(argv):
    if len(argv) != 3:
        print("usage: specdec.py IN.gsc OUT.ply", file=sys.stderr)
        return 2
    try:
        with open(argv[1], "rb") as f:
            data = f.read()
    except OSError as e:
        print(f"specdec: error: {argv[1]}: io: {e.strerror}", file=sys.stderr)
        return 1
    try:
        n, degree, cols = decode(data)
    except DecodeError as e:
        print(f"specdec: error: {argv[1]}: {e}", file=sys.stderr)
        return 1
    write_ply(argv[2], n, degree, cols)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
