// The browser player's page: the clock, the controls, the camera and WebGL2 drawing. Fetching and
// decoding run in the worker (worker.js); this thread only draws what the worker sends.
//
// index.html?url=CLIP             plays CLIP (relative to the page, or absolute) from frame 0
//           &frame=N              starts paused at frame N
//           &camera=x,y,z:tx,ty,tz  the camera (`pstream render --camera`'s syntax); default: the
//                                 clip's framing, as `pstream render` and the viewer frame it
//           &speed=S              clip seconds per second (default 1)
//           &size=WxH             the canvas size in pixels (default: the window's)
//           &flat=1               flat colours, no lighting (as `pstream render --preset debug`)
//           &bench=1              steps through every cached frame once and reports, per frame, the
//                                 worker's decode and sort times and this thread's draw time, then
//                                 steps back to the first frame and reports the decodes
//                                 (window.player.bench; bench/web/run.sh compares them with native)
const params = new URLSearchParams(location.search);
const canvas = document.getElementById('view');
const status = document.getElementById('status');
const errorBox = document.getElementById('error');

const state = {
  ready: false, error: null, playing: !params.has('frame'), speed: Number(params.get('speed') || 1),
  time: 0, frame: -1, shown: 0, distinctShown: 0, stalls: 0, meta: null,
  timing: { decodeMs: 0, sortMs: 0, drawMs: 0, fetchMs: 0 }, cache: null, count: 0, framesDecoded: 0
};
window.player = { state };

// ---- the worker -------------------------------------------------------------------------------

const worker = new Worker('worker.js', { type: 'module' });
let nextId = 1;
const replies = new Map();
worker.onmessage = (event) => {
  const reply = replies.get(event.data.id);
  replies.delete(event.data.id);
  if (event.data.ok) reply.resolve(event.data);
  else reply.reject(new Error(event.data.error));
};
worker.onerror = (event) => fail(`the worker failed: ${event.message}`);
function ask(type, message = {}) {
  return new Promise((resolve, reject) => {
    const id = nextId++;
    replies.set(id, { resolve, reject });
    const { transfer = [], ...rest } = message;
    worker.postMessage({ id, type, ...rest }, transfer);
  });
}

function fail(message) {
  if (state.error) return;
  state.error = message;
  state.playing = false;
  errorBox.textContent = message;
  errorBox.hidden = false;
  console.error(message);
}

// ---- camera -----------------------------------------------------------------------------------

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => { const l = Math.hypot(...a) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

// Column-major, as frame.hpp's look_at and perspective.
function lookAt(eye, target, up) {
  const f = normalize(sub(target, eye)), s = normalize(cross(f, up)), u = cross(s, f);
  return new Float32Array([s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0,
    -dot(s, eye), -dot(u, eye), dot(f, eye), 1]);
}
function perspective(fovY, aspect, near, far) {
  const f = 1 / Math.tan((fovY * Math.PI) / 360);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
    0, 0, (2 * far * near) / (near - far), 0]);
}

const camera = { eye: [0, 0, 5], target: [0, 0, 0], up: [0, 1, 0], fov: 45, near: 0.01, far: 1000 };
function setCameraFromParam(text) {
  const m = /^(-?[\d.e+-]+),(-?[\d.e+-]+),(-?[\d.e+-]+):(-?[\d.e+-]+),(-?[\d.e+-]+),(-?[\d.e+-]+)$/.exec(text);
  if (!m) { fail(`camera=${text}: expected x,y,z:tx,ty,tz`); return; }
  const v = m.slice(1).map(Number);
  camera.eye = v.slice(0, 3);
  camera.target = v.slice(3, 6);
  camera.up = [0, 1, 0];
}

// Drag to orbit about the target, wheel to move nearer or farther.
let drag = null;
canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
canvas.addEventListener('pointerup', () => { drag = null; });
canvas.addEventListener('pointermove', (e) => {
  if (!drag) return;
  const dx = (e.clientX - drag[0]) * 0.01, dy = (e.clientY - drag[1]) * 0.01;
  drag = [e.clientX, e.clientY];
  const offset = sub(camera.eye, camera.target), r = Math.hypot(...offset);
  let yaw = Math.atan2(offset[0], offset[2]) - dx;
  let pitch = Math.asin(Math.max(-1, Math.min(1, offset[1] / r))) + dy;
  pitch = Math.max(-1.5, Math.min(1.5, pitch));
  camera.eye = [camera.target[0] + r * Math.cos(pitch) * Math.sin(yaw), camera.target[1] + r * Math.sin(pitch),
    camera.target[2] + r * Math.cos(pitch) * Math.cos(yaw)];
  camera.up = [0, 1, 0];
  requestFrame(true);
});
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  const k = Math.exp(e.deltaY * 0.001);
  camera.eye = camera.target.map((t, i) => t + (camera.eye[i] - t) * k);
  requestFrame(true);
}, { passive: false });

// ---- WebGL2 sprites ---------------------------------------------------------------------------

const gl = canvas.getContext('webgl2', { antialias: false, premultipliedAlpha: true, preserveDrawingBuffer: true });
const kVertex = `#version 300 es
layout(location = 0) in vec4 a_center;   // xyz, radius (world units)
layout(location = 1) in vec4 a_color;    // RGBA8, normalised
uniform mat4 u_view, u_projection;
uniform vec4 u_default_color;
uniform bool u_has_color;
out vec2 v_local;
out vec4 v_color;
void main() {
  vec2 corner = vec2(float(gl_VertexID & 1) * 2.0 - 1.0, float(gl_VertexID >> 1) * 2.0 - 1.0);
  vec4 view = u_view * vec4(a_center.xyz, 1.0);
  view.xy += corner * a_center.w;        // a camera-facing square of the particle's radius
  v_local = corner;
  v_color = u_has_color ? a_color : u_default_color;
  gl_Position = u_projection * view;
}`;
// The native sprite's profile and lights (src/render/sprites.cpp): a soft round coverage, and a
// sphere under the sprite lit by a key (wrapped diffuse), a fill and a rim light over an ambient,
// in view space. No shadows, no tone map. u_lit off: flat colours (`pstream render --preset debug`).
const kFragment = `#version 300 es
precision mediump float;
in vec2 v_local;
in vec4 v_color;
uniform bool u_lit;
out vec4 o_color;
const vec3 kKey = vec3(0.45, 0.65, 0.61), kFill = vec3(-0.62, -0.2, 0.76);
void main() {
  float r2 = dot(v_local, v_local);
  if (r2 > 1.0) discard;
  float a = v_color.a * (1.0 - smoothstep(0.55, 1.0, sqrt(r2)));
  float light = 1.0;
  if (u_lit) {
    vec3 n = vec3(v_local, sqrt(1.0 - r2));
    float key = clamp(dot(n, kKey) * 0.6 + 0.4, 0.0, 1.0);
    light = 0.16 + 0.84 * key + 0.12 * max(dot(n, kFill), 0.0) + 0.2 * pow(1.0 - n.z, 3.0);
  }
  o_color = vec4(v_color.rgb * light * a, a);   // premultiplied
}`;

function compile(type, source) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}
let program, instanceBuffer, vao, uniforms;
// The instance buffer at the clip's largest (twice max_count: between two frames the dying and
// the newborn are both drawn), made once; each image updates it in place.
function sizeInstanceBuffer(maxCount) {
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.bufferData(gl.ARRAY_BUFFER, Math.max(20, 2 * maxCount * 20), gl.DYNAMIC_DRAW);
}
function setupGl() {
  if (!gl) throw new Error('this browser has no WebGL2');
  program = gl.createProgram();
  gl.attachShader(program, compile(gl.VERTEX_SHADER, kVertex));
  gl.attachShader(program, compile(gl.FRAGMENT_SHADER, kFragment));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  uniforms = Object.fromEntries(['u_view', 'u_projection', 'u_default_color', 'u_has_color', 'u_lit']
    .map((n) => [n, gl.getUniformLocation(program, n)]));
  vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  instanceBuffer = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.enableVertexAttribArray(0);
  gl.vertexAttribPointer(0, 4, gl.FLOAT, false, 20, 0);
  gl.vertexAttribDivisor(0, 1);
  gl.enableVertexAttribArray(1);
  gl.vertexAttribPointer(1, 4, gl.UNSIGNED_BYTE, true, 20, 16);
  gl.vertexAttribDivisor(1, 1);
}

let benchmarking = false;
const onePixel = new Uint8Array(4);

// The background: the native renderer's (`pstream render`'s clear colour).
const kBackground = [0.02, 0.025, 0.035, 1];

function draw(reply) {
  const start = performance.now();
  const w = canvas.width, h = canvas.height;
  gl.viewport(0, 0, w, h);
  gl.clearColor(...kBackground);
  gl.clear(gl.COLOR_BUFFER_BIT);
  gl.useProgram(program);
  gl.bindVertexArray(vao);
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.bufferSubData(gl.ARRAY_BUFFER, 0, new Uint8Array(reply.instances, 0, reply.count * 20));
  gl.uniformMatrix4fv(uniforms.u_view, false, reply.view);
  gl.uniformMatrix4fv(uniforms.u_projection, false, perspective(camera.fov, w / h, camera.near, camera.far));
  gl.uniform4fv(uniforms.u_default_color, [0.45, 0.65, 0.95, 0.9]);
  gl.uniform1i(uniforms.u_lit, params.has('flat') ? 0 : 1);
  gl.uniform1i(uniforms.u_has_color, state.meta.attributes.some((a) => a.name === 'color') ? 1 : 0);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);  // premultiplied "over", back to front
  gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, reply.count);
  // Chrome's finish() need not wait for the GPU process; reading a pixel back does (the benchmark
  // pays that to time the draw; playback does not).
  if (benchmarking) gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, onePixel);
  else gl.finish();
  state.timing.drawMs = performance.now() - start;
}

// ---- the clock --------------------------------------------------------------------------------

let inFlight = false, wanted = false, lastTick = 0, waitingSince = 0;

const seen = new Set();

// The clip time (seconds, the clip's own clock) `time` seconds into playback, looping: the last
// frame is held for one frame interval, then the first comes again.
function clipTime(time) {
  const m = state.meta, t0 = m.times[0], span = m.times[m.frames - 1] - t0 + 1 / m.fps;
  return t0 + (((time % span) + span) % span);
}

let shownTime = NaN;
let spare = null;  // the last image's particle buffer, drawn: handed back to the worker with the next request
function recycled(message) {
  if (spare) { message.recycle = spare; message.transfer = [spare]; spare = null; }
  return message;
}
// Asks the worker for the particles at clip time `time` along the current view and draws them.
async function drawAt(time) {
  const view = lookAt(camera.eye, camera.target, camera.up);
  const reply = await ask('show', recycled({ time, view, sorted: true }));
  reply.view = view;
  draw(reply);
  spare = reply.instances;
  return reply;
}

async function requestFrame(force = false) {
  if (!state.ready || state.error) return;
  if (inFlight) { wanted = wanted || force; return; }
  const time = clipTime(state.time);
  if (!force && time === shownTime) return;
  inFlight = true;
  try {
    const reply = await drawAt(time);
    shownTime = time;
    state.frame = reply.frame;
    state.fraction = reply.fraction;
    state.count = reply.count;
    state.shown++;
    if (!seen.has(reply.frame)) { seen.add(reply.frame); state.distinctShown = seen.size; }
    state.timing.decodeMs = reply.decodeMs;
    state.timing.sortMs = reply.sortMs;
    state.timing.fetchMs = reply.fetchMs;
    state.cache = reply.cache;
    state.buffersMade = reply.buffersMade;
    state.framesDecoded = reply.framesDecoded;
    updateControls();
  } catch (e) {
    fail(e.message);
  } finally {
    inFlight = false;
  }
  if (wanted) { wanted = false; requestFrame(true); }
}

function tick(now) {
  const dt = lastTick ? (now - lastTick) / 1000 : 0;
  lastTick = now;
  if (state.ready && state.playing && !state.error) {
    if (inFlight) {
      // The frame due is not decoded yet: the clock holds (a stall) instead of skipping ahead.
      if (!waitingSince) waitingSince = now;
    } else {
      if (waitingSince && now - waitingSince > 1000 / state.meta.fps) state.stalls++;
      waitingSince = 0;
      state.time += dt * state.speed;
    }
    requestFrame();
  }
  drawCacheView();
  requestAnimationFrame(tick);
}

// ---- controls ---------------------------------------------------------------------------------

const playButton = document.getElementById('play');
const scrub = document.getElementById('scrub');
const speed = document.getElementById('speed');
const cacheView = document.getElementById('cache');

playButton.onclick = () => { state.playing = !state.playing && !state.error; updateControls(); };
scrub.oninput = () => {
  state.time = state.meta.times[Number(scrub.value)] - state.meta.times[0];
  requestFrame(true);
};
speed.value = String(state.speed);
speed.onchange = () => { state.speed = Number(speed.value); };

function updateControls() {
  playButton.textContent = state.playing ? 'Pause' : 'Play';
  if (!state.meta) return;
  scrub.value = String(state.frame);
  const c = state.cache || {};
  status.textContent = `frame ${state.frame + 1}/${state.meta.frames} · ${state.count.toLocaleString()} particles · ` +
    `decode ${state.timing.decodeMs.toFixed(1)} ms · sort ${state.timing.sortMs.toFixed(1)} ms · ` +
    `draw ${state.timing.drawMs.toFixed(1)} ms · ${(c.bytes / 1e6 || 0).toFixed(1)} MB in ${c.requests || 0} ` +
    `requests at ${(c.bandwidth || 0).toFixed(1)} MB/s · ${c.retries || 0} retries · ${state.stalls} stalls`;
}

// Chunk states: fetched (blue), on their way (amber), not fetched (grey); the playhead in white.
function drawCacheView() {
  const ctx = cacheView.getContext('2d');
  const w = cacheView.width, h = cacheView.height;
  ctx.fillStyle = '#333';
  ctx.fillRect(0, 0, w, h);
  const states = state.cache && state.cache.states;
  if (!states || !states.length) return;
  for (let i = 0; i < states.length; ++i) {
    ctx.fillStyle = ['#444', '#d9a030', '#4a90d9'][states[i]];
    ctx.fillRect(Math.floor((i * w) / states.length), 0, Math.max(1, Math.ceil(w / states.length) - 1), h);
  }
  if (state.meta.frames > 1) {
    ctx.fillStyle = '#fff';
    ctx.fillRect(Math.round((state.frame / (state.meta.frames - 1)) * (w - 2)), 0, 2, h);
  }
}

// ---- start ------------------------------------------------------------------------------------

async function start() {
  const url = params.get('url');
  if (!url) {
    fail('no clip: open index.html?url=CLIP.pstream (a URL relative to this page, or absolute)');
    return;
  }
  const size = /^(\d+)x(\d+)$/.exec(params.get('size') || '');
  canvas.width = size ? Number(size[1]) : Math.floor(canvas.clientWidth * devicePixelRatio);
  canvas.height = size ? Number(size[2]) : Math.floor(canvas.clientHeight * devicePixelRatio);
  if (size) { canvas.style.width = `${size[1]}px`; canvas.style.height = `${size[2]}px`; }
  try {
    setupGl();
    const opened = await ask('open', { url, aspect: canvas.width / canvas.height });
    state.meta = opened.meta;
    sizeInstanceBuffer(state.meta.max_count);
    Object.assign(camera, opened.meta.camera);
    if (params.has('camera')) setCameraFromParam(params.get('camera'));
    scrub.max = String(Math.max(0, state.meta.frames - 1));
    document.title = `${url.split('/').pop()} · ParticleStream`;
    if (params.has('frame')) {
      const f = Math.min(Math.max(0, Number(params.get('frame'))), state.meta.frames - 1);
      state.time = state.meta.times[f] - state.meta.times[0];
    }
    state.ready = state.meta.frames > 0;
    if (!state.ready) fail(`${url}: the clip has no frames`);
    updateControls();
    if (params.has('bench') && state.ready) {
      state.ready = false;  // the clock stays out of the way
      await bench();
      return;
    }
    requestFrame(true);
  } catch (e) {
    fail(e.message);
  }
}

// For tests and tools: frame `frame`'s decoded records, as the native Reader gives them.
window.player.records = async (frame) => {
  const reply = await ask('records', { frame });
  return { count: reply.count, bytes: new Uint8Array(reply.bytes) };
};
// Every cached frame in order, paused: per-frame decode (worker), sort and pack (worker) and draw
// (this thread, to a pixel read back) times, with their medians and 95th percentiles; then every
// step back to the first frame, each image between two frames: the decode times and the frames
// decoded.
async function bench() {
  state.playing = false;
  benchmarking = true;
  const rows = { decodeMs: [], sortMs: [], drawMs: [], fetchMs: [], count: [] };
  let decodedBefore = 0;
  for (let f = 0; f < state.meta.frames; ++f) {
    const reply = await drawAt(state.meta.times[f]);
    decodedBefore = reply.framesDecoded;
    rows.decodeMs.push(reply.decodeMs);
    rows.sortMs.push(reply.sortMs);
    rows.fetchMs.push(reply.fetchMs);
    rows.drawMs.push(state.timing.drawMs);
    rows.count.push(reply.count);
  }
  // Then backwards, each image halfway between two cached frames: what a step back costs.
  // Most steps decode nothing (the frames are kept) and a few walk from the keyframe: the mean is
  // what playing backwards costs.
  const back = [], t = state.meta.times;
  let decodedAfter = decodedBefore;
  for (let f = t.length - 2; f >= 0; --f) {
    const reply = await drawAt(t[f] + 0.5 * (t[f + 1] - t[f]));
    back.push(reply.decodeMs);
    decodedAfter = reply.framesDecoded;
  }
  const stepsBack = back.length;
  const stat = (v) => {
    const s = [...v].sort((a, b) => a - b);
    return { median: s[Math.floor(s.length / 2)], p95: s[Math.min(s.length - 1, Math.floor(s.length * 0.95))],
      mean: s.reduce((a, b) => a + b, 0) / s.length, max: s[s.length - 1] };
  };
  const result = { frames: state.meta.frames, particles: stat(rows.count).median, decodeMs: stat(rows.decodeMs),
    sortMs: stat(rows.sortMs), drawMs: stat(rows.drawMs), fetchMs: stat(rows.fetchMs), size: [canvas.width, canvas.height],
    backDecodeMs: stepsBack ? stat(back) : null, stepsBack,
    backFramesDecoded: decodedAfter - decodedBefore };
  window.player.bench = result;
  status.textContent = `bench: ${result.frames} frames of ${result.particles.toLocaleString()} particles: decode ` +
    `${result.decodeMs.median.toFixed(2)} ms, sort ${result.sortMs.median.toFixed(2)} ms, ` +
    `draw ${result.drawMs.median.toFixed(2)} ms (medians)`;
}

// Resolves when frame `frame` is drawn (paused), for screenshots and tests; a fraction (12.5) is
// that far towards the next cached frame, interpolated.
window.player.show = async (frame) => {
  state.playing = false;
  while (inFlight) await new Promise((r) => setTimeout(r, 5));
  const times = state.meta.times, f = Math.floor(frame), towards = frame - f;
  state.time = times[f] - times[0] + (towards > 0 && f + 1 < times.length ? towards * (times[f + 1] - times[f]) : 0);
  await requestFrame(true);
};

start();
requestAnimationFrame(tick);
