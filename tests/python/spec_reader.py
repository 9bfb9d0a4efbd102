"""A .pstream reader written from docs/format.md alone, to show that the spec is enough to decode a
clip: every version (1 to 5), both frame codecs, every word coding, derived velocity.

It shares no code with the library: the container, the chunks, the particle codec's bodies and
the records are decoded here as the spec says, with xxHash, LZ4 and Zstandard called through
ctypes (the spec names those formats, not our code). It is slow (Python loops over particles)
and checks only what it needs to find its way; the library's reader is the validating one.

    for index, records in SpecReader("clip.pstream").frames_records(): ...
"""
import ctypes
import struct

import numpy as np

_xxhash = ctypes.CDLL("libxxhash.so.0")
_xxhash.XXH3_64bits.restype = ctypes.c_uint64
_xxhash.XXH3_64bits.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
_lz4 = ctypes.CDLL("liblz4.so.1")
_lz4.LZ4_decompress_safe.restype = ctypes.c_int
_lz4.LZ4_decompress_safe.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_int]
_zstd = ctypes.CDLL("libzstd.so.1")
_zstd.ZSTD_decompress.restype = ctypes.c_size_t
_zstd.ZSTD_decompress.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t]
_zstd.ZSTD_getFrameContentSize.restype = ctypes.c_ulonglong
_zstd.ZSTD_getFrameContentSize.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
_zstd.ZSTD_isError.restype = ctypes.c_uint
_zstd.ZSTD_isError.argtypes = [ctypes.c_size_t]
_zstd.ZSTD_createDCtx.restype = ctypes.c_void_p
_zstd.ZSTD_freeDCtx.argtypes = [ctypes.c_void_p]
_zstd.ZSTD_DCtx_reset.argtypes = [ctypes.c_void_p, ctypes.c_int]
_zstd.ZSTD_decompressStream.restype = ctypes.c_size_t


class _Buffer(ctypes.Structure):  # ZSTD_inBuffer and ZSTD_outBuffer have the same layout
    _fields_ = [("data", ctypes.c_void_p), ("size", ctypes.c_size_t), ("pos", ctypes.c_size_t)]


_zstd.ZSTD_decompressStream.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Buffer), ctypes.POINTER(_Buffer)]

MAGIC = b"PSTREAM\0"
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
QUANTIZED, EXACT, CONSTANT, ID, RELATIVE, DERIVED = range(6)
CODED = (QUANTIZED, EXACT, RELATIVE)  # words with values and steps in the decoder's state


class SpecError(Exception):
    pass


def xxh3(data):
    return _xxhash.XXH3_64bits(bytes(data), len(data))


def unzz32(u):
    u &= 0xFFFFFFFF
    return ((u >> 1) ^ -(u & 1)) & 0xFFFFFFFF


def unzz64(u):
    return ((u >> 1) ^ -(u & 1)) & 0xFFFFFFFFFFFFFFFF


def int32(v):
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v >= 1 << 31 else v


def plane_block(body, at, n, width):
    """n values of `width` bytes, byte j of value t at j*n + t; returns (values, next offset)."""
    values = [0] * n
    for j in range(width):
        plane = body[at + j * n:at + (j + 1) * n]
        if len(plane) != n:
            raise SpecError(f"body ends inside a plane at {at + j * n}")
        for t, byte in enumerate(plane):
            values[t] |= byte << (8 * j)
    return values, at + width * n


class SpecReader:
    def __init__(self, path):
        with open(path, "rb") as f:
            self.data = f.read()
        d = self.data
        if d[:8] != MAGIC:
            raise SpecError("not a .pstream")
        (self.version, self.header_size) = struct.unpack_from("<II", d, 8)
        if self.version == 1:
            if xxh3(d[:152]) != struct.unpack_from("<Q", d, 152)[0]:
                raise SpecError("header checksum")
        else:
            if xxh3(d[:184]) != struct.unpack_from("<Q", d, 184)[0]:
                raise SpecError("header checksum")
        (self.flags, self.fps, self.time0, self.frame_count, self.chunk_size, self.chunk_count, self.stream_size,
         self.record_size, self.attribute_count) = struct.unpack_from("<QddQQQQII", d, 16)
        (self.tables_offset, self.tables_size, tables_checksum) = struct.unpack_from("<QQQ", d, 128)
        if self.version == 1:
            self.frame_codec, self.order, self.lossless, self.keyframe_interval = 0, 0, 0, 1
        else:
            (self.frame_codec, self.order, self.lossless, _, self.keyframe_interval) = struct.unpack_from(
                "<IBBHI", d, 152)
        tables = d[self.tables_offset:self.tables_offset + self.tables_size]
        if xxh3(tables) != tables_checksum:
            raise SpecError("tables checksum")
        at = 0
        self.strings = []
        for _ in range(3):
            (n,) = struct.unpack_from("<I", tables, at)
            self.strings.append(tables[at + 4:at + 4 + n].decode())
            at += 4 + n
        self.attributes = []
        for _ in range(self.attribute_count):
            name = tables[at:at + 32].rstrip(b"\0").decode()
            (kind, components, _, offset) = struct.unpack_from("<BBHI", tables, at + 32)
            self.attributes.append((name, kind, components, offset))
            at += 40
        self.words = []
        if self.frame_codec == 1:
            for _ in range(self.record_size // 4):
                (coding, step, error, base) = struct.unpack_from("<B3xffI", tables, at)
                self.words.append((coding, step, error, base))
                at += 16
        self.frames = []
        entry = 48 if self.version == 1 else 64
        for _ in range(self.frame_count):
            count, byte_offset, time = struct.unpack_from("<QQd", tables, at)
            if self.version == 1:
                packet_offset, packet_size, keyframe = byte_offset, count * self.record_size, True
            else:
                packet_offset, packet_size, flags = struct.unpack_from("<QII", tables, at + 48)
                keyframe = bool(flags & 1)
            self.frames.append((count, time, packet_offset, packet_size, keyframe))
            at += entry
        self.chunks = []
        for _ in range(self.chunk_count):
            self.chunks.append(struct.unpack_from("<QQQHHI", tables, at))
            at += 32
        if at != len(tables):
            raise SpecError(f"tables of {len(tables)} bytes, {at} read")

    def stream(self):
        """The chunked stream: every chunk checked and decoded, in order."""
        out = bytearray()
        for i, (offset, stored, checksum, codec, _, _) in enumerate(self.chunks):
            raw_size = min(self.chunk_size, self.stream_size - i * self.chunk_size)
            payload = self.data[offset:offset + stored]
            if xxh3(payload) != checksum:
                raise SpecError(f"chunk {i}: checksum")
            if codec == 0:
                raw = payload
            elif codec == 1:
                dst = ctypes.create_string_buffer(raw_size)
                if _lz4.LZ4_decompress_safe(payload, dst, len(payload), raw_size) != raw_size:
                    raise SpecError(f"chunk {i}: LZ4")
                raw = dst.raw
            elif codec == 2:
                dst = ctypes.create_string_buffer(raw_size)
                if _zstd.ZSTD_decompress(dst, raw_size, payload, len(payload)) != raw_size:
                    raise SpecError(f"chunk {i}: zstd")
                raw = dst.raw
            else:
                raise SpecError(f"chunk {i}: codec {codec}")
            if len(raw) != raw_size:
                raise SpecError(f"chunk {i}: {len(raw)} bytes, expected {raw_size}")
            out += raw
        return bytes(out)

    def frames_records(self):
        """Yields (frame, records as bytes) for every frame in order."""
        stream = self.stream()
        if self.frame_codec == 0:
            for f, (count, _, offset, size, _) in enumerate(self.frames):
                yield f, stream[offset:offset + size]
            return
        decoder = _ParticleDecoder(self)
        try:
            for f, (count, _, offset, size, keyframe) in enumerate(self.frames):
                yield f, decoder.decode(stream[offset:offset + size], count, keyframe)
        finally:
            decoder.close()


class _ParticleDecoder:
    def __init__(self, reader):
        self.r = reader
        self.coded = [w for w, (coding, _, _, _) in enumerate(reader.words) if coding in CODED]
        self.k_of = {w: k for k, w in enumerate(self.coded)}
        self.has_ids = any(coding == ID for coding, _, _, _ in reader.words)
        self.derived = [w for w, (coding, _, _, _) in enumerate(reader.words) if coding == DERIVED]
        self.P = 0
        self.Q = [[] for _ in self.coded]
        self.D = [[] for _ in self.coded]
        self.I = []
        self.A = []
        self.dctx = _zstd.ZSTD_createDCtx() if reader.version >= 4 else None

    def close(self):
        if self.dctx:
            _zstd.ZSTD_freeDCtx(self.dctx)
            self.dctx = None

    def body(self, packet):
        if self.r.version < 4:  # one whole zstd frame that states its content size
            size = _zstd.ZSTD_getFrameContentSize(packet, len(packet))
            if size >= 1 << 32:
                raise SpecError("packet: a zstd frame without its content size")
            dst = ctypes.create_string_buffer(size)
            n = _zstd.ZSTD_decompress(dst, size, packet, len(packet))
            if _zstd.ZSTD_isError(n):
                raise SpecError("packet: zstd")
            return dst.raw[:n]
        if packet[:4] == ZSTD_MAGIC:
            _zstd.ZSTD_DCtx_reset(self.dctx, 1)  # ZSTD_reset_session_only: a new frame
        src = ctypes.create_string_buffer(bytes(packet), len(packet))
        out = bytearray()
        chunk = ctypes.create_string_buffer(1 << 20)
        inb = _Buffer(ctypes.cast(src, ctypes.c_void_p), len(packet), 0)
        while True:
            outb = _Buffer(ctypes.cast(chunk, ctypes.c_void_p), len(chunk), 0)
            n = _zstd.ZSTD_decompressStream(self.dctx, ctypes.byref(outb), ctypes.byref(inb))
            if _zstd.ZSTD_isError(n):
                raise SpecError("packet: zstd")
            out += chunk.raw[:outb.pos]
            if inb.pos == inb.size and outb.pos < outb.size:
                return bytes(out)

    def decode(self, packet, count, keyframe):
        r = self.r
        body = self.body(packet)
        C = len(self.coded)
        N, prev_count, O, M = struct.unpack_from("<IIII", body, 0)
        if N != count:
            raise SpecError(f"body count {N}, frame index {count}")
        at = 16
        heads = []
        for _ in range(C):
            heads.append(struct.unpack_from("<8B", body, at))
            at += 8
        id_bytes = 0
        if self.has_ids:
            id_bytes = body[at]
            at += 4
        ops = []
        for _ in range(O):
            ops.append(struct.unpack_from("<III", body, at))
            at += 12
        if keyframe:
            if O or prev_count:
                # Links (version 6 on, id order): which particles continue the frame before's. They
                # decode nothing: every particle of a keyframe is new.
                if r.version < 6 or r.order != 1:
                    raise SpecError("a keyframe with operations (links need version 6 and id order)")
                ops, prev_count = [], 0
            self.P = 0
        if prev_count != self.P:
            raise SpecError(f"prev_count {prev_count}, the state holds {self.P}")
        S = sum(op[0] for op in ops)
        B = -(-S // 1024)
        planes = []
        for k in range(C):
            predictor, keep_bytes, new_bytes, motion_bytes, bias_bytes, prior_bytes, keep_packing, _ = heads[k]
            bias, at = plane_block(body, at, B, bias_bytes)
            if keep_packing == 1:
                nibbles = body[at:at + (S + 1) // 2]
                at += (S + 1) // 2
                keep = [(nibbles[t // 2] >> (4 * (t & 1))) & 15 for t in range(S)]
                escapes, at = plane_block(body, at, sum(1 for v in keep if v == 15), keep_bytes)
                it = iter(escapes)
                keep = [15 + next(it) if v == 15 else v for v in keep]
            else:
                keep, at = plane_block(body, at, S, keep_bytes)
            new, at = plane_block(body, at, M, new_bytes)
            motion = [0] * M
            if r.version >= 3:
                motion, at = plane_block(body, at, M, motion_bytes)
            prior = [0] * N
            if keyframe and r.version >= 3:
                prior, at = plane_block(body, at, N, prior_bytes)
            planes.append((predictor, bias, keep, new, motion, prior))
        ids, at = plane_block(body, at, M, id_bytes)
        if at != len(body):
            raise SpecError(f"body of {len(body)} bytes, {at} read")

        Q2 = [[0] * N for _ in range(C)]
        D2 = [[0] * N for _ in range(C)]
        I2 = [0] * N
        A2 = [0] * N
        P2 = [[0] * N for _ in range(C)]  # a keyframe's prior steps
        d1 = [[0] * N for _ in range(C)]  # each particle's step before its last (derived velocity)
        for k in range(C):
            predictor, bias_deltas, keep, new, motion, prior = planes[k]
            bias, b = [], 0
            for v in bias_deltas:
                b = (b + unzz32(v)) & 0xFFFFFFFF
                bias.append(b)
            Q, D, Qn, Dn = self.Q[k], self.D[k], Q2[k], D2[k]
            if keyframe:
                q = d = p = 0
                for j in range(N):
                    q = (q + unzz32(new[j])) & 0xFFFFFFFF
                    d = (d + unzz32(motion[j])) & 0xFFFFFFFF
                    p = (p + unzz32(prior[j])) & 0xFFFFFFFF
                    Qn[j], Dn[j], P2[k][j] = q, d, p
                continue
            i = j = s = nt = 0
            m = 0
            for keep_n, drop, insert in ops:
                for _ in range(keep_n):
                    step = ((D[i] if predictor == 1 else 0) + bias[s // 1024] + unzz32(keep[s])) & 0xFFFFFFFF
                    Qn[j] = (Q[i] + step) & 0xFFFFFFFF
                    Dn[j] = step
                    d1[k][j] = D[i]
                    i, j, s = i + 1, j + 1, s + 1
                i += drop
                for _ in range(insert):
                    m = (m + unzz32(motion[nt])) & 0xFFFFFFFF
                    Qn[j] = ((Qn[j - 1] if j > 0 else 0) + unzz32(new[nt])) & 0xFFFFFFFF
                    Dn[j] = m
                    j, nt = j + 1, nt + 1
        # Ids and the step states, which follow the operations too.
        derived_ks = [self.k_of[r.words[w][3]] for w in self.derived]
        if keyframe:
            idv = 0
            for j in range(N):
                idv = (idv + unzz64(ids[j])) & 0xFFFFFFFFFFFFFFFF
                I2[j] = idv
                if derived_ks:
                    moved = any(D2[k][j] != 0 for k in derived_ks)
                    primed = any(P2[k][j] != 0 for k in derived_ks)
                    for k in derived_ks:
                        d1[k][j] = P2[k][j]
                    if moved:
                        A2[j] = 2 if primed else 1
                    elif primed:
                        for k in derived_ks:
                            D2[k][j] = P2[k][j]
                        A2[j] = 3
        else:
            i = j = nt = 0
            for keep_n, drop, insert in ops:
                for _ in range(keep_n):
                    I2[j] = self.I[i] if self.has_ids else 0
                    if derived_ks:
                        A2[j] = {0: 1, 3: 4}.get(self.A[i], 2)
                    i, j = i + 1, j + 1
                i += drop
                for _ in range(insert):
                    I2[j] = ((I2[j - 1] if j > 0 else 0) + unzz64(ids[nt])) & 0xFFFFFFFFFFFFFFFF
                    if derived_ks:
                        A2[j] = 3 if any(D2[k][j] != 0 for k in derived_ks) else 0
                    j, nt = j + 1, nt + 1

        records = np.zeros((N, r.record_size // 4), dtype=np.uint32)
        for w, (coding, step, error, base) in enumerate(r.words):
            if coding in CODED:
                q = np.array(Q2[self.k_of[w]], dtype=np.uint32)
                if coding == QUANTIZED:
                    origin = np.uint32(base).view(np.float32)
                    value = q.view(np.int32).astype(np.float32) * np.float32(step) + origin
                    records[:, w] = value.astype(np.float32).view(np.uint32)
                elif coding == RELATIVE:
                    records[:, w] = q << np.uint32(base)
                else:
                    records[:, w] = q
            elif coding == CONSTANT:
                records[:, w] = base
            elif coding == ID:
                halves = np.array(I2, dtype=np.uint64)
                first = min(v for v, (c, _, _, _) in enumerate(r.words) if c == ID)
                records[:, w] = (halves >> np.uint64(32 * (w - first))).astype(np.uint32)
            elif coding == DERIVED:
                k = self.k_of[base]
                numerators = []
                for j in range(N):
                    d0, dp = int32(D2[k][j]), int32(d1[k][j])
                    numerators.append({0: 0, 1: 2 * d0, 2: 3 * d0 - dp, 3: 2 * d0, 4: 4 * d0 - 2 * dp}[A2[j]])
                value = np.array(numerators, dtype=np.int64).astype(np.float32) * np.float32(step)
                records[:, w] = value.astype(np.float32).view(np.uint32)
            else:
                raise SpecError(f"word {w}: coding {coding}")
        self.P, self.Q, self.D, self.I, self.A = N, Q2, D2, I2, A2
        return records.tobytes()
