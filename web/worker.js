// The browser player's worker: range requests (fetch) and decoding (the C++ decoder in
// WebAssembly). The page's main thread only draws; every byte is fetched and decoded here.
//
// Remote-streaming rules (docs/streaming.md, as the native HTTP source keeps them):
// - one byte range per request (object stores answer one), of whole chunks;
// - look-ahead: the chunks of the next frames are fetched before they are needed, neighbouring
//   ranges merged into one request of up to kMergeBytes;
// - at most kInFlight requests at once;
// - transient failures (network errors, 408, 429, 5xx, short bodies, stalls) retried kRetries
//   times with jittered exponential backoff;
// - every response is checked against what the open saw (size, ETag, Last-Modified): a file
//   replaced on the server is an error, never a mix of two files.
import createDecoder from './pstream.js';
import { ZSTDDecoder } from './zstddec-stream.mjs';

const kPrefixBytes = 256 * 1024;    // fetched at open: header and tables usually fit
const kMergeBytes = 4 << 20;        // the largest merged request
const kInFlight = 4;
const kRetries = 4;
const kRetryBase = 100, kRetryMax = 2000;  // ms
const kStallMs = 10000;             // a request that has not finished in this long is retried
const kLookAheadBytes = 16 << 20;   // fetched ahead of the playhead
const kCacheBytes = 192 << 20;      // fetched bytes kept (least recently used dropped first)
const kOk = 0, kError = 1, kNeedBytes = 2;

class FatalError extends Error {}

class RangeCache {
  constructor(url) {
    this.url = url;
    this.size = 0;
    this.validator = null;           // ETag and Last-Modified at open
    this.ranges = [];                // {offset, bytes, used} sorted by offset, not overlapping
    this.pending = new Map();        // chunk index or span key -> the request's promise
    this.active = 0;
    this.waiting = [];               // resolvers for a free request slot
    this.stats = { requests: 0, bytes: 0, retries: 0, failures: 0, ms: 0, inFlight: 0 };
    this.clock = 0;
    this.fatal = null;
  }

  describe(offset, end) { return `${this.url}: bytes ${offset}-${end - 1}`; }

  async open() {
    const want = kPrefixBytes;
    const { bytes, total, validator } = await this.request(0, want, true);
    this.size = total;
    this.validator = validator;
    this.insert(0, bytes);
  }

  // One range request, retried; returns the body.
  async request(offset, end, opening = false) {
    let attempt = 0;
    for (;;) {
      if (this.fatal) throw this.fatal;
      const started = performance.now();
      const abort = new AbortController();
      const timer = setTimeout(() => abort.abort(), kStallMs);
      let why;
      try {
        this.stats.requests++;
        this.stats.inFlight++;
        const response = await fetch(this.url, {
          headers: { Range: `bytes=${offset}-${end - 1}` }, signal: abort.signal, cache: 'no-store'
        });
        if (response.status === 206) {
          const m = /^bytes (\d+)-(\d+)\/(\d+)$/.exec(response.headers.get('Content-Range') || '');
          if (!m || Number(m[1]) !== offset) {
            throw new FatalError(`${this.describe(offset, end)}: the server answered with Content-Range ` +
              `'${response.headers.get('Content-Range')}', expected bytes ${offset}-...`);
          }
          const total = Number(m[3]);
          const validator = [response.headers.get('ETag'), response.headers.get('Last-Modified')];
          if (!opening) this.check(offset, end, total, validator);
          const bytes = new Uint8Array(await response.arrayBuffer());
          const expected = Math.min(end, total) - offset;
          if (bytes.length !== expected) {
            why = `a short body (${bytes.length} of ${expected} bytes)`;
          } else {
            this.stats.bytes += bytes.length;
            this.stats.ms += performance.now() - started;
            return { bytes, total, validator };
          }
        } else if (response.status === 200) {
          throw new FatalError(`${this.describe(offset, end)}: the server ignores range requests ` +
            `(it sent the whole file with status 200); serve the clip from a server that answers Range (206)`);
        } else if (response.status === 408 || response.status === 429 || response.status >= 500) {
          why = `HTTP ${response.status}`;
        } else {
          throw new FatalError(`${this.describe(offset, end)}: HTTP ${response.status} ${response.statusText}`);
        }
      } catch (e) {
        if (e instanceof FatalError) throw this.fail(e);
        why = abort.signal.aborted ? `no answer within ${kStallMs / 1000} s` : `${e.message || e}`;
      } finally {
        clearTimeout(timer);
        this.stats.inFlight--;
      }
      if (attempt >= kRetries) {
        throw this.fail(new FatalError(`${this.describe(offset, end)}: ${why}, after ${attempt + 1} attempts`));
      }
      this.stats.retries++;
      const backoff = Math.min(kRetryMax, kRetryBase * 2 ** attempt) * Math.random();
      attempt++;
      await new Promise((r) => setTimeout(r, backoff));
    }
  }

  check(offset, end, total, validator) {
    const [etag, modified] = validator, [etag0, modified0] = this.validator;
    let change = null;
    if (total !== this.size) change = `its size is now ${total} bytes, was ${this.size}`;
    else if (etag0 && etag && etag !== etag0) change = `its ETag is now ${etag}, was ${etag0}`;
    else if (modified0 && modified && modified !== modified0) change = `Last-Modified is now ${modified}, was ${modified0}`;
    if (change) {
      throw new FatalError(`${this.describe(offset, end)}: the file changed on the server since it was opened ` +
        `(${change}); reload the page to play the new file`);
    }
  }

  fail(e) {
    this.stats.failures++;
    if (!this.fatal) this.fatal = e;
    return e;
  }

  insert(offset, bytes) {
    this.ranges.push({ offset, bytes, used: ++this.clock });
    this.ranges.sort((a, b) => a.offset - b.offset);
    let total = this.ranges.reduce((s, r) => s + r.bytes.length, 0);
    while (total > kCacheBytes && this.ranges.length > 1) {
      let oldest = 0;
      for (let i = 1; i < this.ranges.length; ++i) if (this.ranges[i].used < this.ranges[oldest].used) oldest = i;
      total -= this.ranges[oldest].bytes.length;
      this.ranges.splice(oldest, 1);
    }
  }

  // The fetched range holding [offset, end) whole, or null.
  find(offset, end) {
    for (const r of this.ranges) {
      if (r.offset <= offset && end <= r.offset + r.bytes.length) {
        r.used = ++this.clock;
        return r;
      }
    }
    return null;
  }

  covered(offset, end) {
    for (const r of this.ranges) {
      if (r.offset <= offset && offset < r.offset + r.bytes.length) offset = r.offset + r.bytes.length;
    }
    return offset >= end;
  }

  // Fetches [offset, end) unless it is fetched or on its way (reads before the chunk table is known).
  async ensureSpan(offset, end) {
    if (this.covered(offset, end)) return;
    await this.fetchInto(`${offset}-${end}`, offset, end, []);
  }

  // Fetches the chunks `indices` (of `spans`, [offset, end) each) that are neither fetched nor on
  // their way: runs of neighbours merged into single requests of up to kMergeBytes.
  async ensureChunks(indices, spans) {
    const waits = [];
    let run = null;
    const flush = () => {
      if (run) waits.push(this.fetchInto(`c${run.first}`, spans[run.first][0], spans[run.last][1], run.chunks));
      run = null;
    };
    for (const i of indices) {
      const [a, b] = spans[i];
      if (this.covered(a, b)) continue;
      if (this.pending.has(i)) { waits.push(this.pending.get(i)); continue; }
      if (run && run.last === i - 1 && b - spans[run.first][0] <= kMergeBytes) {
        run.last = i;
        run.chunks.push(i);
      } else {
        flush();
        run = { first: i, last: i, chunks: [i] };
      }
    }
    flush();
    await Promise.all(waits);
  }

  fetchInto(key, offset, end, chunks) {
    if (this.pending.has(key)) return this.pending.get(key);
    const p = this.slot().then(() => this.request(offset, end))
      .then(({ bytes }) => this.insert(offset, bytes))
      .finally(() => {
        this.pending.delete(key);
        for (const c of chunks) this.pending.delete(c);
        this.release();
      });
    this.pending.set(key, p);
    for (const c of chunks) this.pending.set(c, p);
    return p;
  }

  async slot() {
    if (this.active < kInFlight) { this.active++; return; }
    await new Promise((r) => this.waiting.push(r));
    this.active++;
  }

  release() {
    this.active--;
    const next = this.waiting.shift();
    if (next) next();
  }
}

let M = null;            // the decoder module
let cache = null;
let meta = null;
let chunkSpans = [];     // [offset, end) of each chunk
let viewPtr = 0;         // the view matrix's 16 floats in the module's heap, allocated at open
let projectionPtr = 0;   // the projection's, for the liquid (pw_liquid)
const spares = [];       // particle buffers the page has handed back
let buffersMade = 0;     // particle buffers made (the test checks that playing makes no more than two)
// The look's settings (chooseLook), its particle layout among them (instanceBytes: x, y, z,
// radius, RGBA8, and velocity where the look streaks; pstream_wasm.cpp), and the page's parameters
// that chose it.
let lookStyle = { instanceBytes: 20 };
let lookChosen = {};
// zstddec's streaming build (zstd's own decoder in WebAssembly). Its exports, which _init is
// handed, give the one stream a particle clip's keyframe group is (format version 4 on).
let zx = null;
class StreamingZSTD extends ZSTDDecoder {
  _init(result) {
    zx = result.instance.exports;
    super._init(result);
  }
}
const zstd = new StreamingZSTD();
const stream = { dctx: 0, ok: false, io: 0, input: 0, inputSize: 0, output: 0, outputSize: 0 };

function readFetched(offset, ptr, size) {
  const r = cache.find(offset, offset + size);
  if (!r) return 1;
  M.HEAPU8.set(r.bytes.subarray(offset - r.offset, offset - r.offset + size), ptr);
  return 0;
}

function zstdDecompress(out, capacity, src, srcSize) {
  try {
    const decoded = zstd.decode(M.HEAPU8.subarray(src, src + srcSize), capacity);
    if (decoded.length === 0 || decoded.length > capacity) return -1;
    M.HEAPU8.set(decoded, out);
    return decoded.length;
  } catch (e) {
    return -1;
  }
}

// A buffer of at least `size` bytes in zstddec's heap, replacing `ptr` (of `had` bytes) when smaller.
function zstdBuffer(ptr, had, size) {
  if (ptr && had >= size) return [ptr, had];
  if (ptr) zx.free(ptr);
  const made = zx.malloc(size);
  if (!made) throw new Error('out of memory');
  return [made, size];
}

// The next packet of a zstd stream (the stream's first when `restart`) into at most `capacity`
// bytes at `out`: the size, or -1 (corrupt, too large, or not following a decoded packet).
function zstdStream(out, capacity, src, srcSize, restart) {
  try {
    if (restart) {
      if (stream.dctx) zx.ZSTD_freeDCtx(stream.dctx);
      stream.dctx = zx.ZSTD_createDCtx();
      if (!stream.io) stream.io = zx.malloc(24);  // ZSTD_inBuffer, then ZSTD_outBuffer (wasm32)
      stream.ok = stream.dctx !== 0 && stream.io !== 0;
    }
    if (!stream.ok) return -1;
    stream.ok = false;  // until this packet decodes whole
    [stream.input, stream.inputSize] = zstdBuffer(stream.input, stream.inputSize, Math.max(srcSize, 1));
    [stream.output, stream.outputSize] = zstdBuffer(stream.output, stream.outputSize, capacity);
    new Uint8Array(zx.memory.buffer).set(M.HEAPU8.subarray(src, src + srcSize), stream.input);
    const view = () => new DataView(zx.memory.buffer);  // anew after anything that may grow it
    const io = stream.io;
    view().setUint32(io, stream.input, true);
    view().setUint32(io + 4, srcSize, true);
    view().setUint32(io + 8, 0, true);
    view().setUint32(io + 12, stream.output, true);
    view().setUint32(io + 16, capacity, true);
    view().setUint32(io + 20, 0, true);
    while (view().getUint32(io + 8, true) < srcSize) {
      if (zx.ZSTD_decompressStream(stream.dctx, io + 12, io) < 0) return -1;  // an error code
      if (view().getUint32(io + 20, true) === capacity) return -1;
    }
    const size = view().getUint32(io + 20, true);
    if (size === capacity) return -1;
    M.HEAPU8.set(new Uint8Array(zx.memory.buffer, stream.output, size), out);
    stream.ok = true;
    return size;
  } catch (e) {
    return -1;
  }
}

// The chunks frames [from, to] read, in order.
// (Frames of no particles have empty packets; a clip of only those has no chunks at all.)
function chunksOf(from, to) {
  const out = [];
  const last = Math.min(M._pw_last_chunk(to), chunkSpans.length - 1);
  for (let c = M._pw_first_chunk(from); c <= last; ++c) out.push(c);
  return out;
}

// Calls a decoder function until it has every byte it needs.
async function withBytes(call) {
  for (;;) {
    const status = call();
    if (status === kOk) return;
    if (status === kError) throw new FatalError(M.UTF8ToString(M._pw_error()));
    const offset = M._pw_need_offset(), size = M._pw_need_size();
    // The chunk holding the need, whole (readers read whole chunks; the header and tables are
    // read at open, before the chunk table is known).
    const chunk = chunkSpans.findIndex(([a, b]) => a <= offset && offset + size <= b);
    if (chunk >= 0) await cache.ensureChunks([chunk], chunkSpans);
    else await cache.ensureSpan(offset, offset + size);
  }
}

// Starts fetching the chunks of the frames after `frame`, up to kLookAheadBytes of them.
function lookAhead(frame) {
  if (frame + 1 >= meta.frames) return;
  const chunks = [];
  let bytes = 0;
  for (let c = M._pw_first_chunk(frame + 1); c < chunkSpans.length && bytes < kLookAheadBytes; ++c) {
    chunks.push(c);
    bytes += chunkSpans[c][1] - chunkSpans[c][0];
  }
  cache.ensureChunks(chunks, chunkSpans).catch(() => {});  // a failure surfaces when the frame is needed
}

function chunkStates() {
  return Uint8Array.from(chunkSpans, ([a, b], i) => (cache.covered(a, b) ? 2 : cache.pending.has(i) ? 1 : 0));
}

// Decodes what `decoder` (a call into the module) needs: the chunks of frames [from, to], fetched
// first (merged requests), then anything else it asks for; then starts the look-ahead.
async function decodeFrames(from, to, decoder) {
  const fetchStart = performance.now();
  await cache.ensureChunks(chunksOf(from, to), chunkSpans);
  const fetchMs = performance.now() - fetchStart;
  const decodeStart = performance.now();
  await withBytes(decoder);
  lookAhead(to);
  return { fetchMs, decodeMs: performance.now() - decodeStart, framesDecoded: M._pw_frames_decoded() };
}

// The look (`preset`, `color-by`, `ramp`, `ramp-range`, `ramp-attribute`: the page's parameters,
// `pstream render`'s flags) set in the module through the library's presets and checks; its
// settings, or the library's refusal.
function setStyle(look) {
  const strings = [look.preset, look.colorBy, look.ramp, look.rampAttribute, look.backdrop].map((text) => {
    const n = M.lengthBytesUTF8(text || '') + 1, ptr = M._malloc(n);
    M.stringToUTF8(text || '', ptr, n);
    return ptr;
  });
  const range = look.rampRange || null;
  try {
    const status = M._pw_style(strings[0], strings[1], strings[2], range ? 1 : 0, range ? range[0] : 0,
      range ? range[1] : 0, strings[3], strings[4]);
    if (status !== 0) throw new FatalError(M.UTF8ToString(M._pw_error()));
  } finally {
    strings.forEach((ptr) => M._free(ptr));
  }
  return JSON.parse(M.UTF8ToString(M._pw_style_json()));
}

// The look, kept as lookStyle: what the page draws with. `liquidLacks` are the WebGL2 extensions
// the liquid's passes need that the page's browser lacks (player.js): a look the browser cannot
// draw is refused as the library refuses one, and the look before stays (set in the module again).
function chooseLook(look = {}, liquidLacks = []) {
  const style = setStyle(look);
  if (style.look === 'liquid' && liquidLacks.length) {
    setStyle(lookChosen);
    throw new FatalError(`the liquid needs WebGL2's ${liquidLacks.join(', ')}, which this browser lacks`);
  }
  lookChosen = look;
  lookStyle = style;
  return lookStyle;
}

// `n` floats the decoder wrote at `ptr`, copied out of its heap.
const floatsAt = (ptr, n) => Array.from(M.HEAPF32.subarray(ptr >> 2, (ptr >> 2) + n));

const handlers = {
  async open({ url, aspect, look, liquidLacks, cameraAt }) {
    await zstd.init();
    M = await createDecoder({ readFetched, zstdDecompress, zstdStream });
    cache = new RangeCache(new URL(url, self.location.href).href);
    await cache.open();
    const name = M.lengthBytesUTF8(cache.url) + 1, ptr = M._malloc(name);
    M.stringToUTF8(cache.url, ptr, name);
    try {
      await withBytes(() => M._pw_open(cache.size, ptr));
    } finally {
      M._free(ptr);
    }
    meta = JSON.parse(M.UTF8ToString(M._pw_metadata()));
    const style = chooseLook(look, liquidLacks);
    viewPtr = M._malloc(64);
    projectionPtr = M._malloc(64);
    chunkSpans = [];
    for (let i = 0; i < meta.chunks.length; i += 2) chunkSpans.push([meta.chunks[i], meta.chunks[i] + meta.chunks[i + 1]]);
    if (meta.frames > 0) lookAhead(-1);
    const cam = M._malloc(48 + 24);
    if (cameraAt) M.HEAPF32.set(cameraAt, (cam >> 2) + 12);
    M._pw_camera(aspect || 16 / 9, cameraAt ? cam + 48 : 0, cam);
    const c = floatsAt(cam, 12);
    M._free(cam);
    const camera = { eye: c.slice(0, 3), target: c.slice(3, 6), up: c.slice(6, 9), fov: c[9], near: c[10], far: c[11] };
    return { meta: { ...meta, url: cache.url, size: cache.size, camera }, style };
  },

  // The particles at clip time `time` (seconds; interpolated between the cached frames around it,
  // as the native player does), sorted back to front along `view`.
  // The particles travel in one of two buffers of the clip's largest size, made once: the page
  // hands each back (`recycle`) with its next request, so playing allocates no particle buffers.
  async show({ time, view, projection, size, sorted, recycle }) {
    if (recycle) spares.push(recycle);
    const from = M._pw_first_needed(time), to = M._pw_last_needed(time);
    const timing = await decodeFrames(from, to, () => M._pw_show(time));
    M.HEAPF32.set(view, viewPtr >> 2);
    const sortStart = performance.now();
    const count = M._pw_pack(viewPtr, sorted ? 1 : 0);
    const sortMs = performance.now() - sortStart;
    const ptr = M._pw_instances();
    let instances = spares.pop();
    if (instances && instances.byteLength < lookStyle.instanceBytes * 2 * meta.max_count) instances = null;  // the look changed its layout
    if (!instances) {
      instances = new ArrayBuffer(lookStyle.instanceBytes * 2 * meta.max_count);
      buffersMade++;
    }
    new Uint8Array(instances, 0, count * lookStyle.instanceBytes).set(M.HEAPU8.subarray(ptr, ptr + count * lookStyle.instanceBytes));
    // A self-shadowing look: the light's view and projection, and the eye's blending order; the
    // liquid: the same view and projection, for its shadow on the ground.
    const shadow = lookStyle.shadows || lookStyle.look === 'liquid' ? floatsAt(M._pw_shadow(), 33) : null;
    // And its slices: where each starts in `instances`, and the end (frame.hpp: slice_starts).
    let slices = null;
    if (lookStyle.shadows) {
      const at = M._pw_slices() >> 2;
      slices = Array.from(M.HEAPU32.subarray(at + 1, at + 2 + M.HEAPU32[at]));
    }
    const lights = floatsAt(M._pw_lights(), 6);
    // The liquid: what its passes take for this image and this projection (frame.hpp: liquid_passes).
    let liquid = null;
    if (lookStyle.look === 'liquid') {
      M.HEAPF32.set(projection, projectionPtr >> 2);
      liquid = JSON.parse(M.UTF8ToString(M._pw_liquid(projectionPtr, size[0], size[1])));
    }
    const s = cache.stats;
    const at = M._pw_frame_at(time);
    return {
      frame: Math.floor(at), fraction: at - Math.floor(at), count, instances, buffersMade, ...timing, sortMs, shadow, slices, lights,
      liquid,
      cache: { states: chunkStates(), requests: s.requests, bytes: s.bytes, retries: s.retries, inFlight: s.inFlight,
        bandwidth: s.ms > 0 ? s.bytes / 1e3 / s.ms : 0 },
      transfer: [instances]
    };
  },

  // Another look (the page's look menu), through the library's presets and checks.
  async look({ look, liquidLacks }) {
    return { style: chooseLook(look, liquidLacks) };
  },

  // Frame `frame`'s decoded records, as the native Reader gives them (for tests and tools).
  async records({ frame }) {
    await decodeFrames(M._pw_first_needed(meta.times[frame]), frame, () => M._pw_decode(frame));
    const ptr = M._pw_records(), n = M._pw_count() * meta.record_size;
    const bytes = M.HEAPU8.slice(ptr, ptr + n).buffer;
    return { frame, count: M._pw_count(), bytes, transfer: [bytes] };
  }
};

// One message at a time, in order: the decoder keeps its place in the keyframe group.
let queue = Promise.resolve();
self.onmessage = (event) => {
  const { id, type } = event.data;
  queue = queue.then(async () => {
    try {
      const result = await handlers[type](event.data);
      const transfer = result.transfer || [];
      delete result.transfer;
      self.postMessage({ id, ok: true, ...result }, transfer);
    } catch (e) {
      self.postMessage({ id, ok: false, error: e.message || String(e) });
    }
  });
};
