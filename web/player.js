// The browser player's page: the clock, the controls, the camera and WebGL2 drawing. Fetching and
// decoding run in the worker (worker.js); this thread only draws what the worker sends.
//
// index.html?url=CLIP             plays CLIP (relative to the page, or absolute) from frame 0
//           &frame=N              starts paused at frame N
//           &camera=x,y,z:tx,ty,tz  the camera (`pstream render --camera`'s syntax); default: the
//                                 clip's framing, as `pstream render` and the viewer frame it
//           &speed=S              clip seconds per second (default 1)
//           &size=WxH             the canvas size in pixels (default: the window's)
//           &preset=NAME          the look, as `pstream render --preset`: sprites (default), sparks,
//                                 smoke, liquid-sprites, debug (also the page's look menu)
//           &color-by=stored|speed|attribute, &ramp=NAME, &ramp-range=LOW,HIGH, &ramp-attribute=NAME
//                                 the colouring, as `pstream render`'s flags of those names
//           &bench=1              steps through every cached frame once and reports, per frame, the
//                                 worker's decode and sort times and this thread's draw time, then
//                                 steps back to the first frame and reports the decodes
//                                 (window.player.bench; bench/web/run.sh compares them with native)
import { shaders } from './shaders.js';

const params = new URLSearchParams(location.search);
const canvas = document.getElementById('view');
const status = document.getElementById('status');
const errorBox = document.getElementById('error');

const state = {
  ready: false, error: null, playing: !params.has('frame'), speed: Number(params.get('speed') || 1),
  time: 0, frame: -1, shown: 0, distinctShown: 0, stalls: 0, meta: null,
  timing: { decodeMs: 0, sortMs: 0, drawMs: 0, fetchMs: 0 }, cache: null, count: 0, framesDecoded: 0,
  lookNote: ''
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
// `camera=x,y,z:tx,ty,tz`'s eye and target (the worker makes the camera: Camera::looking), or null.
function cameraParam() {
  if (!params.has('camera')) return null;
  const text = params.get('camera');
  const m = /^(-?[\d.e+-]+),(-?[\d.e+-]+),(-?[\d.e+-]+):(-?[\d.e+-]+),(-?[\d.e+-]+),(-?[\d.e+-]+)$/.exec(text);
  if (!m) throw new Error(`camera=${text}: expected x,y,z:tx,ty,tz`);
  return m.slice(1).map(Number);
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
  camera.near *= k;  // the near plane keeps its share of the distance (Camera::looking's rule): nothing close is clipped
  requestFrame(true);
}, { passive: false });

// ---- WebGL2 sprites ---------------------------------------------------------------------------

const gl = canvas.getContext('webgl2', { antialias: false, premultipliedAlpha: true, preserveDrawingBuffer: true });

// The native sprite pass (src/render/sprites.cpp) in WebGL2, with its shaders (shaders.js: the
// files of src/render/shaders/, which the native renderer embeds): camera-facing quads, or
// streaks along their screen-space velocity over the look's shutter, with the soft round profile
// and the key, fill and rim lights, accumulated in a half-float buffer; then bloom, exposure and
// the tone map over the background. The look's settings come from the library's presets (the
// worker's chooseLook); the colours arrive ramped where the look colours by speed or an attribute.
const kVertexPrelude = '#version 300 es\n', kFragmentPrelude = '#version 300 es\nprecision highp float;\nprecision highp int;\n';
const kVertex = `${kVertexPrelude}
layout(location = 0) in vec4 a_center;    // xyz, radius (world units)
layout(location = 1) in vec4 a_color;     // RGBA8, normalised
layout(location = 2) in vec3 a_velocity;  // world units per second (looks that streak; else 0)
uniform mat4 u_view, u_light_view;
uniform vec4 u_tint;
uniform float u_opacity;
uniform int u_pass;                       // 0: the image, 1: the light buffer (self-shadowing looks)
out vec4 v_color;
out vec2 v_light_uv;                      // where the sprite's centre falls in the light buffer
${shaders['sprite_corner.glsl']}
void main() {
  vec2 corner = vec2(float(gl_VertexID & 1) * 2.0 - 1.0, float(gl_VertexID >> 1) * 2.0 - 1.0);
  vec4 p = vec4(a_center.xyz, 1.0), view = u_view * p;
  float radius = a_center.w;
  v_color = a_color * u_tint;
  v_color.a *= u_opacity;
  v_light_uv = vec2(-1.0);
  if (u_pass == 1) {
    gl_Position = light_corner(u_light_view * p, radius, corner);
    return;
  }
  v_light_uv = (u_light_projection * (u_light_view * p)).xy * 0.5 + 0.5;
  floor_size(sprite_pixels(radius, view.z), radius, v_color.a);
  gl_Position = sprite_corner(view, mat3(u_view) * a_velocity, radius, corner, v_color.a);
}`;
const kFragment = kFragmentPrelude + shaders['sprite.frag'];
const kFullScreen = kVertexPrelude + shaders['full_screen.vert'];
const kComposite = kFragmentPrelude + shaders['composite.frag'];
const kBloom = kFragmentPrelude + shaders['bloom.frag'];
// The sky and the ground grid behind the particles (the native backdrop's shader).
const kBackdrop = kFragmentPrelude + shaders['sky.glsl'] + shaders['ground_ray.glsl'] + shaders['backdrop.frag'];
// The self-shadowing sprites' shadow on that ground, from the light buffer.
const kGroundShadow = kFragmentPrelude + shaders['ground_ray.glsl'] + shaders['ground_shadow.frag'];
// The liquid (src/render/liquid.cpp's passes, with its shaders): sphere splats into a depth and a
// thickness buffer, the two-dimensional depth filter (natively a compute pass, here a fragment
// pass over the same function), normals, and the surface over the scene; spray over it.
const kSamplerPrecision = 'precision highp sampler2D;\n';
const kLiquidSplatVertex = `${kVertexPrelude}precision highp float;\n${kSamplerPrecision}
layout(location = 0) in vec4 a_center;    // xyz, radius (world units)
layout(location = 2) in vec3 a_velocity;  // world units per second (with foam by speed; else 0)
uniform mat4 u_view;
uniform float u_fixed_radius;             // > 0: every particle's radius
${shaders['liquid_splat.glsl']}
void main() {
  float r = u_fixed_radius > 0.0 ? u_fixed_radius : a_center.w;
  gl_Position = liquid_splat_corner(u_view * vec4(a_center.xyz, 1.0), r, length(a_velocity));
}`;
const kLiquidSplat = kFragmentPrelude + shaders['liquid_splat.frag'];
const liquidFilterSource = (pairs) => `${kFragmentPrelude}${kSamplerPrecision}const int kPairs = ${pairs};
${shaders['liquid_filter.glsl']}
layout(location = 0) out vec4 o_out;
void main() { o_out = vec4(liquid_filter(ivec2(gl_FragCoord.xy)), 0.0, 0.0); }`;
const kLiquidNormals = kFragmentPrelude + kSamplerPrecision + shaders['view_position.glsl'] + shaders['liquid_normal.frag'];
const kLiquidComposite = kFragmentPrelude + kSamplerPrecision + shaders['view_position.glsl'] + shaders['sky.glsl'] +
  shaders['liquid_composite.frag'];

function compile(type, source) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}
function link(vertex, fragment, names) {
  const program = gl.createProgram();
  gl.attachShader(program, compile(gl.VERTEX_SHADER, vertex));
  gl.attachShader(program, compile(gl.FRAGMENT_SHADER, fragment));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  return { program, u: Object.fromEntries(names.map((n) => [n, gl.getUniformLocation(program, n)])) };
}
let sprites, composite, bloomBlur, backdrop, groundShadow, liquid, instanceBuffer, vao, look;
// Render targets: the accumulated light at the canvas's size, and the bloom's two buffers at half
// of it (across, then down), made once at start.
const targets = {};
function target(width, height, format = targets.format, depth = null) {
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texStorage2D(gl.TEXTURE_2D, 1, format, width, height);
  for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
    [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) gl.texParameteri(gl.TEXTURE_2D, k, v);
  const framebuffer = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, texture, 0);
  if (depth) gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
  if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error('a render target is not renderable');
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  return { texture, framebuffer, width, height };
}
// The instance buffer at the clip's largest (twice max_count: between two frames the dying and
// the newborn are both drawn), made once; each image updates it in place.
function sizeInstanceBuffer(maxCount) {
  const bytes = look.instanceBytes;
  gl.bindVertexArray(vao);
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.bufferData(gl.ARRAY_BUFFER, Math.max(bytes, 2 * maxCount * bytes), gl.DYNAMIC_DRAW);
  if (bytes >= 32) {
    gl.enableVertexAttribArray(2);
    gl.vertexAttribDivisor(2, 1);
  } else {
    gl.disableVertexAttribArray(2);
    gl.vertexAttrib3f(2, 0, 0, 0);
  }
  pointInstances(0);
}
// The instanced attributes from particle `first` on (WebGL2 has no base instance: a slice of a
// self-shadowing look starts its attributes there).
function pointInstances(first) {
  const bytes = look.instanceBytes, at = first * bytes;
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.vertexAttribPointer(0, 4, gl.FLOAT, false, bytes, at);
  gl.vertexAttribPointer(1, 4, gl.UNSIGNED_BYTE, true, bytes, at + 16);
  if (bytes >= 32) gl.vertexAttribPointer(2, 3, gl.FLOAT, false, bytes, at + 20);
}

// The liquid renders to 32-bit float buffers, filters them bilinearly and adds thicknesses up in
// them: the extensions for that which this browser lacks (phones' GPUs often have no
// OES_texture_float_linear). The worker refuses the liquid where any is missing, with
// the library's other refusals, so that the look before stays (chooseLook).
let liquidLacks = [];

function setupGl() {
  if (!gl) throw new Error('this browser has no WebGL2');
  sprites = link(kVertex, kFragment, ['u_view', 'u_projection', 'u_tint', 'u_opacity', 'u_shutter', 'u_min_pixels',
    'u_viewport_height', 'u_lit', 'u_mode', 'u_key', 'u_fill', 'u_sprite', 'u_textured', 'u_light_buffer', 'u_pass', 'u_light_view',
    'u_light_projection', 'u_shadows', 'u_shadow_blur', 'u_light_texel', 'u_shadow_density']);
  composite = link(kFullScreen, kComposite, ['u_hdr', 'u_bloom', 'u_bloom_strength', 'u_exposure', 'u_tone_map']);
  backdrop = link(kFullScreen, kBackdrop, ['u_view', 'u_projection', 'u_viewport', 'u_ground', 'u_ground_height', 'u_grid']);
  groundShadow = link(kFullScreen, kGroundShadow, ['u_view', 'u_projection', 'u_viewport', 'u_ground_height',
    'u_light_view', 'u_light_projection', 'u_light_buffer', 'u_light_texel', 'u_strength']);
  bloomBlur = link(kFullScreen, kBloom, ['u_source', 'u_step', 'u_size', 'u_sigma', 'u_taps']);
  // Half floats where the browser renders to them (EXT_color_buffer_float: nearly all); else
  // 8 bits, which clamps the light before the tone map (the status line says so).
  targets.hdr = !!gl.getExtension('EXT_color_buffer_float');
  liquidLacks = ['EXT_color_buffer_float', 'OES_texture_float_linear', 'EXT_float_blend'].filter((e) => !gl.getExtension(e));
  targets.format = targets.hdr ? gl.RGBA16F : gl.RGBA8;
  targets.light = target(canvas.width, canvas.height);
  const w = Math.max(1, (canvas.width + 1) >> 1), h = Math.max(1, (canvas.height + 1) >> 1);
  targets.bloom = [target(w, h), target(w, h)];
  vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  instanceBuffer = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.enableVertexAttribArray(0);
  gl.vertexAttribDivisor(0, 1);
  gl.enableVertexAttribArray(1);
  gl.vertexAttribDivisor(1, 1);
}

// The liquid's programs and buffers, made on its first image (and the buffers again when the
// image's size changes).
function liquidPasses(pairs) {
  if (liquid && liquid.pairs === pairs) return liquid;
  liquid = {
    pairs,
    splat: link(kLiquidSplatVertex, kLiquidSplat, ['u_view', 'u_projection', 'u_pass', 'u_thickness', 'u_foam_speed',
      'u_foam_thickness', 'u_fixed_radius', 'u_shadow_depth']),
    filter: link(kFullScreen, liquidFilterSource(pairs), ['u_depth', 'u_size', 'u_radius_at_1', 'u_range', 'u_mode',
      'u_scale', 'u_taps']),
    normals: link(kFullScreen, kLiquidNormals, ['u_depth', 'u_size', 'u_projection', 'u_range']),
    composite: link(kFullScreen, kLiquidComposite, ['u_depth', 'u_normal', 'u_thickness', 'u_scene', 'u_viewport',
      'u_liquid_size', 'u_projection', 'u_view', 'u_light', 'u_color', 'u_absorb', 'u_color_depth', 'u_refraction',
      'u_opacity_depth', 'u_output', 'u_radius_at_1']),
    size: ''
  };
  return liquid;
}
function liquidTargets(lw, lh, w, h) {
  const key = `${lw}x${lh}/${w}x${h}`;
  if (liquid.size === key) return;
  for (const t of [liquid.raw, ...(liquid.smooth || []), liquid.thickness, liquid.normal, liquid.scene]) {
    if (t) { gl.deleteFramebuffer(t.framebuffer); gl.deleteTexture(t.texture); }
  }
  if (liquid.depth) gl.deleteRenderbuffer(liquid.depth);
  liquid.depth = gl.createRenderbuffer();
  gl.bindRenderbuffer(gl.RENDERBUFFER, liquid.depth);
  gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT32F, lw, lh);
  liquid.raw = target(lw, lh, gl.RG32F, liquid.depth);  // depth x coverage, coverage
  liquid.smooth = [target(lw, lh, gl.RG32F), target(lw, lh, gl.RG32F)];
  liquid.thickness = target(lw, lh, gl.R32F);
  liquid.normal = target(lw, lh, gl.RGBA16F);
  liquid.scene = target(w, h, gl.RGBA8);
  liquid.size = key;
}

// The backdrop (look.backdrop: the library's choice, as `pstream render --backdrop`) or the
// plain background, with the depth buffer cleared or written as the ground's.
function drawBackground(view, projection) {
  const w = canvas.width, h = canvas.height;
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.viewport(0, 0, w, h);
  gl.clearColor(...look.background);  // the native renderer's (frame.hpp: kDefaultBackground)
  gl.clearDepth(1);
  gl.depthMask(true);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  if (!look.backdrop) return;
  gl.useProgram(backdrop.program);
  const u = backdrop.u;
  gl.uniformMatrix4fv(u.u_view, false, view);
  gl.uniformMatrix4fv(u.u_projection, false, projection);
  gl.uniform2f(u.u_viewport, w, h);
  gl.uniform1i(u.u_ground, look.backdrop.ground ? 1 : 0);
  gl.uniform1f(u.u_ground_height, look.backdrop.groundHeight);
  gl.uniform1f(u.u_grid, look.backdrop.grid > 0 ? look.backdrop.grid : 1);
  gl.disable(gl.BLEND);
  gl.enable(gl.DEPTH_TEST);
  gl.depthFunc(gl.ALWAYS);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
  gl.depthFunc(gl.LESS);
  gl.disable(gl.DEPTH_TEST);
}

// The ground under a light buffer (`light`: a target; `shadow`: its view and projection, from the
// worker) darkened by `strength` times the opacity above it, multiplied over the canvas
// (ShadowBuffer::darken_ground).
function darkenGround(view, projection, shadow, light, strength) {
  const g = groundShadow.u;
  gl.useProgram(groundShadow.program);
  gl.uniformMatrix4fv(g.u_view, false, view);
  gl.uniformMatrix4fv(g.u_projection, false, projection);
  gl.uniform2f(g.u_viewport, canvas.width, canvas.height);
  gl.uniform1f(g.u_ground_height, look.backdrop.groundHeight);
  gl.uniformMatrix4fv(g.u_light_view, false, shadow.slice(0, 16));
  gl.uniformMatrix4fv(g.u_light_projection, false, shadow.slice(16, 32));
  gl.uniform1i(g.u_light_buffer, 0);
  gl.uniform1f(g.u_light_texel, 1 / light.width);
  gl.uniform1f(g.u_strength, strength);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, light.texture);
  gl.disable(gl.DEPTH_TEST);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.ZERO, gl.SRC_COLOR);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
}

// The liquid's image, as LiquidPass::draw makes it natively; `reply.liquid` holds the numbers the
// library derived for it (frame.hpp: liquid_passes).
function drawLiquid(reply, view, projection) {
  const w = canvas.width, h = canvas.height, L = reply.liquid, lw = L.width, lh = L.height;
  const passes = liquidPasses(look.liquid.pairs);
  liquidTargets(lw, lh, w, h);
  gl.bindVertexArray(vao);
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.bufferSubData(gl.ARRAY_BUFFER, 0, new Uint8Array(reply.instances, 0, reply.count * look.instanceBytes));
  const splat = (pass, through = [view, projection]) => {
    gl.useProgram(passes.splat.program);
    const u = passes.splat.u;
    gl.uniformMatrix4fv(u.u_view, false, through[0]);
    gl.uniformMatrix4fv(u.u_projection, false, through[1]);
    gl.uniform1i(u.u_pass, pass);
    gl.uniform1f(u.u_shadow_depth, Math.max(L.shadowDepth, 1e-6));
    gl.uniform1i(u.u_thickness, 0);
    gl.uniform1f(u.u_foam_speed, L.foamSpeed);
    gl.uniform1f(u.u_foam_thickness, L.foamThickness);
    gl.uniform1f(u.u_fixed_radius, L.fixedRadius);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, reply.count);
  };
  const bindTextures = (list) => list.forEach((t, i) => {
    gl.activeTexture(gl.TEXTURE0 + i);
    gl.bindTexture(gl.TEXTURE_2D, t ? t.texture : null);
  });
  gl.disable(gl.BLEND);
  // 1. Sphere depth, nearest wins (nothing bound to the splats' thickness sampler: no feedback).
  bindTextures([null]);
  gl.bindFramebuffer(gl.FRAMEBUFFER, passes.raw.framebuffer);
  gl.viewport(0, 0, lw, lh);
  gl.clearColor(0, 0, 0, 0);
  gl.clearDepth(1);
  gl.depthMask(true);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.enable(gl.DEPTH_TEST);
  gl.depthFunc(gl.LESS);
  splat(0);
  // 2. Thickness, every sphere's chord added.
  gl.bindFramebuffer(gl.FRAMEBUFFER, passes.thickness.framebuffer);
  gl.clear(gl.COLOR_BUFFER_BIT);
  gl.disable(gl.DEPTH_TEST);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.ONE, gl.ONE);
  splat(1);
  gl.disable(gl.BLEND);
  // 3. The depth filter: three smaller passes, then the look's iterations at its radius.
  let smoothed = passes.raw;
  const f = passes.filter;
  gl.useProgram(f.program);
  gl.uniform1f(f.u.u_radius_at_1, L.filterRadiusAt1);
  gl.uniform1f(f.u.u_range, L.range);
  gl.uniform1i(f.u.u_mode, L.filterMode);
  gl.uniform2i(f.u.u_size, lw, lh);
  gl.uniform1i(f.u.u_depth, 0);
  for (let i = 0; i < L.filterPasses; ++i) {
    const out = passes.smooth[i % 2];
    gl.bindFramebuffer(gl.FRAMEBUFFER, out.framebuffer);
    gl.uniform1f(f.u.u_scale, look.liquid.scales[i]);
    gl.uniform3fv(f.u.u_taps, look.liquid.taps[i]);
    bindTextures([smoothed]);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    smoothed = out;
  }
  // 4. Normals from the smoothed depth.
  gl.bindFramebuffer(gl.FRAMEBUFFER, passes.normal.framebuffer);
  gl.useProgram(passes.normals.program);
  gl.uniform1i(passes.normals.u.u_depth, 0);
  gl.uniform2i(passes.normals.u.u_size, lw, lh);
  gl.uniformMatrix4fv(passes.normals.u.u_projection, false, projection);
  gl.uniform1f(passes.normals.u.u_range, L.range);
  bindTextures([smoothed]);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
  // 5. The liquid's shadow on the ground: its sphere chords along the light, as opacities in a
  // light buffer over the clip's bounds, darken the ground.
  // liquid_passes decided: a shadow depth only over a ground (the worker's light view comes with every liquid image).
  const shadow = L.shadowDepth > 0;
  if (shadow) {
    if (!passes.light || passes.light.width !== L.shadowResolution) {
      if (passes.light) { gl.deleteFramebuffer(passes.light.framebuffer); gl.deleteTexture(passes.light.texture); }
      passes.light = target(L.shadowResolution, L.shadowResolution, gl.R16F);
    }
    bindTextures([null]);
    gl.bindFramebuffer(gl.FRAMEBUFFER, passes.light.framebuffer);
    gl.viewport(0, 0, L.shadowResolution, L.shadowResolution);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    splat(3, [reply.shadow.slice(0, 16), reply.shadow.slice(16, 32)]);
    gl.disable(gl.BLEND);
  }
  // 6. What is behind the liquid (with the shadow), copied for refraction; then the surface over it.
  drawBackground(view, projection);
  if (shadow) {
    gl.bindVertexArray(vao);
    darkenGround(view, projection, reply.shadow, passes.light, L.shadowStrength);
    gl.disable(gl.BLEND);
  }
  gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, passes.scene.framebuffer);
  gl.blitFramebuffer(0, 0, w, h, 0, 0, w, h, gl.COLOR_BUFFER_BIT, gl.NEAREST);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.viewport(0, 0, w, h);
  const c = passes.composite, cu = c.u;
  gl.useProgram(c.program);
  [cu.u_depth, cu.u_normal, cu.u_thickness, cu.u_scene].forEach((at, i) => gl.uniform1i(at, i));
  bindTextures([smoothed, passes.normal, passes.thickness, passes.scene]);
  gl.uniform2f(cu.u_viewport, w, h);
  gl.uniform2f(cu.u_liquid_size, lw, lh);
  gl.uniformMatrix4fv(cu.u_projection, false, projection);
  gl.uniformMatrix4fv(cu.u_view, false, view);
  gl.uniform3fv(cu.u_light, reply.lights.slice(0, 3));  // the key light (frame.hpp: sprite_lights)
  gl.uniform3fv(cu.u_color, look.liquid.color);
  gl.uniform3fv(cu.u_absorb, L.absorb);
  gl.uniform1f(cu.u_color_depth, L.colorDepth);
  gl.uniform1f(cu.u_refraction, L.refraction);
  gl.uniform1f(cu.u_opacity_depth, L.opacityDepth);
  gl.uniform1i(cu.u_output, look.liquid.output);
  gl.uniform1f(cu.u_radius_at_1, L.radiusPxAt1);
  gl.enable(gl.DEPTH_TEST);
  gl.depthFunc(gl.LESS);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
  bindTextures([null, null, null, null]);
  // 7. Spray over the surface.
  if (L.spray) {
    bindTextures([passes.thickness]);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.depthMask(false);
    splat(2);
    gl.depthMask(true);
    gl.disable(gl.BLEND);
    bindTextures([null]);
  }
  gl.disable(gl.DEPTH_TEST);
  gl.activeTexture(gl.TEXTURE0);
}

let benchmarking = false;
const onePixel = new Uint8Array(4);


// Blurs the accumulated light into targets.bloom[1]: a Gaussian of `radius` image heights, across
// (halving the resolution through bilinear taps), then down; the weights sum to one.
function blur(radius) {
  const [a, b] = targets.bloom, sigma = Math.max(0.5, radius * a.height);
  gl.useProgram(bloomBlur.program);
  gl.uniform1i(bloomBlur.u.u_source, 0);
  gl.uniform1f(bloomBlur.u.u_sigma, sigma);
  gl.uniform1i(bloomBlur.u.u_taps, Math.min(96, Math.max(1, Math.ceil(3 * sigma))));
  gl.uniform2f(bloomBlur.u.u_size, a.width, a.height);
  gl.viewport(0, 0, a.width, a.height);
  gl.disable(gl.BLEND);
  gl.activeTexture(gl.TEXTURE0);
  for (const [to, from, step] of [[a, targets.light, [1 / a.width, 0]], [b, a, [0, 1 / a.height]]]) {
    gl.bindFramebuffer(gl.FRAMEBUFFER, to.framebuffer);
    gl.bindTexture(gl.TEXTURE_2D, from.texture);
    gl.uniform2f(bloomBlur.u.u_step, ...step);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }
}

function draw(reply) {
  const start = performance.now();
  const w = canvas.width, h = canvas.height, view = reply.view, projection = reply.projection;
  if (look.look === 'liquid') drawLiquid(reply, view, projection);
  else drawSprites(reply, view, projection);
  // Chrome's finish() need not wait for the GPU process; reading a pixel back does (the benchmark
  // pays that to time the draw; playback does not).
  if (benchmarking) gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, onePixel);
  else gl.finish();
  state.timing.drawMs = performance.now() - start;
}

function drawSprites(reply, view, projection) {
  const w = canvas.width, h = canvas.height;
  // The sprites' light, accumulated back to front.
  gl.bindFramebuffer(gl.FRAMEBUFFER, targets.light.framebuffer);
  gl.viewport(0, 0, w, h);
  gl.clearColor(0, 0, 0, 0);
  gl.clear(gl.COLOR_BUFFER_BIT);
  gl.useProgram(sprites.program);
  gl.bindVertexArray(vao);
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.bufferSubData(gl.ARRAY_BUFFER, 0, new Uint8Array(reply.instances, 0, reply.count * look.instanceBytes));
  const u = sprites.u;
  gl.uniformMatrix4fv(u.u_view, false, view);
  gl.uniformMatrix4fv(u.u_projection, false, projection);
  gl.uniform4fv(u.u_tint, look.tint);
  gl.uniform1f(u.u_opacity, look.opacity);
  gl.uniform1f(u.u_shutter, Math.max(look.shutter, 0));
  gl.uniform1f(u.u_min_pixels, Math.max(look.minPixels, 0));
  gl.uniform1f(u.u_viewport_height, h);
  gl.uniform1i(u.u_lit, look.lit ? 1 : 0);
  gl.uniform1i(u.u_mode, look.blend === 1 ? 1 : 0);
  // Its samplers on units of their own: the sprite image, if any (unit 2), and the light buffer
  // (unit 3, bound below only while the image is the target).
  gl.uniform1i(u.u_sprite, 2);
  gl.uniform1i(u.u_textured, spriteImage ? 1 : 0);
  gl.activeTexture(gl.TEXTURE2);
  gl.bindTexture(gl.TEXTURE_2D, spriteImage);
  gl.uniform1i(u.u_light_buffer, 3);
  gl.uniform3fv(u.u_key, reply.lights.slice(0, 3));  // the worker's, for this view (frame.hpp: sprite_lights)
  gl.uniform3fv(u.u_fill, reply.lights.slice(3, 6));
  // Self-shadowing (the worker sorted front to back along the half-angle and cut the order into
  // slices, bounded in count and depth): slices drawn into the image, each lit by the light
  // buffer the slices before laid down, then into the light buffer.
  const shadows = look.shadows && reply.shadow && reply.slices, slices = shadows ? reply.slices.length - 1 : 1;
  gl.uniform1i(u.u_shadows, shadows ? 1 : 0);
  if (shadows) {
    gl.uniformMatrix4fv(u.u_light_view, false, reply.shadow.slice(0, 16));
    gl.uniformMatrix4fv(u.u_light_projection, false, reply.shadow.slice(16, 32));
    gl.uniform1i(u.u_shadow_blur, look.shadowBlur ? 1 : 0);
    gl.uniform1f(u.u_light_texel, 1 / look.shadowResolution);
    gl.uniform1f(u.u_shadow_density, look.shadowDensity);
    if (!targets.shadow) targets.shadow = target(look.shadowResolution, look.shadowResolution, targets.hdr ? gl.R16F : gl.RGBA8);
    gl.bindFramebuffer(gl.FRAMEBUFFER, targets.shadow.framebuffer);
    gl.clear(gl.COLOR_BUFFER_BIT);
  }
  const underFirst = shadows && reply.shadow[32] === 1;
  const ground = look.backdrop && look.backdrop.ground;  // receives the shadows (of the last slice too)
  gl.enable(gl.BLEND);
  for (let k = 0; k < slices; ++k) {
    const first = shadows ? reply.slices[k] : 0, end = shadows ? reply.slices[k + 1] : reply.count;  // the library's slices
    if (end === first) continue;
    if (slices > 1) pointInstances(first);
    gl.bindFramebuffer(gl.FRAMEBUFFER, targets.light.framebuffer);
    gl.viewport(0, 0, w, h);
    gl.activeTexture(gl.TEXTURE3);
    gl.bindTexture(gl.TEXTURE_2D, shadows ? targets.shadow.texture : null);
    if (look.blend === 1) gl.blendFunc(gl.ONE, gl.ONE);
    else if (underFirst) gl.blendFunc(gl.ONE_MINUS_DST_ALPHA, gl.ONE);  // "under": each slice behind the ones before
    else gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);  // premultiplied "over", back to front
    gl.uniform1i(u.u_pass, 0);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, end - first);
    if (!shadows || (k + 1 === slices && !ground)) continue;  // the last slice shadows no slice after it
    gl.bindTexture(gl.TEXTURE_2D, null);  // the light buffer is the target now: no sampler may read it
    gl.bindFramebuffer(gl.FRAMEBUFFER, targets.shadow.framebuffer);
    gl.viewport(0, 0, look.shadowResolution, look.shadowResolution);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.uniform1i(u.u_pass, 1);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, end - first);
  }
  if (slices > 1) pointInstances(0);
  gl.activeTexture(gl.TEXTURE3);
  gl.bindTexture(gl.TEXTURE_2D, null);
  // Bloom, exposure and the tone map, over the background or the backdrop.
  const bloom = look.bloom > 0 && look.bloomRadius > 0;
  if (bloom) blur(look.bloomRadius);
  drawBackground(view, projection);
  if (shadows && ground) darkenGround(view, projection, reply.shadow, targets.shadow, look.groundShadow);  // under every slice
  gl.useProgram(composite.program);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, targets.light.texture);
  gl.activeTexture(gl.TEXTURE1);
  gl.bindTexture(gl.TEXTURE_2D, targets.bloom[1].texture);
  gl.uniform1i(composite.u.u_hdr, 0);
  gl.uniform1i(composite.u.u_bloom, 1);
  gl.uniform1f(composite.u.u_bloom_strength, bloom ? Math.min(look.bloom, 1) : 0);
  gl.uniform1f(composite.u.u_exposure, Math.max(look.exposure, 0));
  gl.uniform1i(composite.u.u_tone_map, look.toneMap);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
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
  const projection = perspective(camera.fov, canvas.width / canvas.height, camera.near, camera.far);
  const reply = await ask('show', recycled({ time, view, projection, size: [canvas.width, canvas.height],
    sorted: look.look !== 'liquid' }));
  reply.view = view;
  reply.projection = projection;
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
// The look: the worker takes the preset through the library (its checks included), the page
// follows, and the address keeps it (a link shows what was shown).
// A look the clip cannot show (sparks without velocities) is refused with the library's message,
// shown over the picture for a few seconds while the look before stays.
const lookChoice = document.getElementById('look');
lookChoice.onchange = async () => {
  const before = params.get('preset');
  params.set('preset', lookChoice.value);
  try {
    while (inFlight) await new Promise((r) => setTimeout(r, 5));
    useLook((await ask('look', { look: lookParams(), liquidLacks })).style);
    history.replaceState(null, '', `${location.pathname}?${params}`);
    requestFrame(true);
  } catch (e) {
    if (before === null) params.delete('preset');
    else params.set('preset', before);
    lookChoice.value = before || 'sprites';
    errorBox.textContent = e.message;
    errorBox.hidden = false;
    setTimeout(() => { if (!state.error) errorBox.hidden = true; }, 6000);
  }
};
// The page's side of a look: its settings, what the browser leaves out, the instance layout.
function useLook(style) {
  look = style;
  const missing = [...look.unsupported, ...(targets.hdr ? [] : ['half-float light (clamped to 8 bits)'])];
  state.lookNote = missing.length ? `not in the browser: ${missing.join(', ')}` : '';
  sizeInstanceBuffer(state.meta.max_count);
  updateControls();
}

function updateControls() {
  playButton.textContent = state.playing ? 'Pause' : 'Play';
  if (!state.meta) return;
  scrub.value = String(state.frame);
  const c = state.cache || {};
  status.textContent = `frame ${state.frame + 1}/${state.meta.frames} · ${state.count.toLocaleString()} particles · ` +
    `decode ${state.timing.decodeMs.toFixed(1)} ms · sort ${state.timing.sortMs.toFixed(1)} ms · ` +
    `draw ${state.timing.drawMs.toFixed(1)} ms · ${(c.bytes / 1e6 || 0).toFixed(1)} MB in ${c.requests || 0} ` +
    `requests at ${(c.bandwidth || 0).toFixed(1)} MB/s · ${c.retries || 0} retries · ${state.stalls} stalls` +
    (state.lookNote ? ` · ${state.lookNote}` : '');
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

// The sprite image (`texture=URL`, as `pstream render --texture`; the sprite look's, not the
// liquid's): its bytes as the native renderer reads them (no colour conversion, alpha straight:
// the bitmap's options, which WebGL's unpack flags do not override for a bitmap), its first row
// first, sampled as natively (bilinear, repeating) and drawn at the sprite's top.
let spriteImage = null;
async function loadSpriteImage(src) {
  let response;
  try {
    response = await fetch(new URL(src, location.href));
  } catch (e) {
    throw new Error(`texture=${src}: ${e.message}`);
  }
  if (!response.ok) throw new Error(`texture=${src}: HTTP ${response.status} ${response.statusText}`);
  let image;
  try {
    image = await createImageBitmap(await response.blob(), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
  } catch (e) {
    throw new Error(`texture=${src}: not an image the browser can read (${e.message})`);
  }
  const texture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, texture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, image);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.bindTexture(gl.TEXTURE_2D, null);
  image.close();
  return texture;
}

// The look's parameters, as `pstream render`'s flags: preset, color-by, ramp, ramp-range,
// ramp-attribute, backdrop.
function lookParams() {
  const look = { preset: params.get('preset') || '', colorBy: params.get('color-by') || '',
    ramp: params.get('ramp') || '', rampAttribute: params.get('ramp-attribute') || '',
    backdrop: params.get('backdrop') || '' };
  if (params.has('ramp-range')) {
    const m = /^(-?[\d.e+-]+),(-?[\d.e+-]+)$/.exec(params.get('ramp-range'));
    if (!m) throw new Error(`ramp-range=${params.get('ramp-range')}: expected LOW,HIGH`);
    look.rampRange = [Number(m[1]), Number(m[2])];
  }
  return look;
}

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
    if (params.has('texture')) spriteImage = await loadSpriteImage(params.get('texture'));
    const opened = await ask('open', { url, aspect: canvas.width / canvas.height, look: lookParams(), liquidLacks,
      cameraAt: cameraParam() });
    state.meta = opened.meta;
    useLook(opened.style);
    if ([...lookChoice.options].some((o) => o.value === params.get('preset'))) lookChoice.value = params.get('preset');
    Object.assign(camera, opened.meta.camera);
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
