// The web player in headless Chromium (run by tests/web/run.sh under tests/http/with_server.sh).
//   node player_test.mjs playback   (nginx)  plays 60 frames; the canvas is not blank; a frame's
//                                             decoded records equal the native decoder's; its image
//                                             matches the native renderer's within the tolerances below
//   node player_test.mjs faults     (fault server)  latency and 503s are retried and the frames are
//                                             exact; a changed file, 500s forever and a 404 end in an
//                                             error on the page naming the URL, and the tab still answers
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';

import { launch } from './chromium.mjs';

const env = process.env;
const base = env.PSTREAM_TEST_URL_BASE;
const site = `${base}${env.WEB_SITE}/index.html`;
const frame = Number(env.WEB_FRAME);
const mode = process.argv[2];

// The image tolerances (docs/web.md): the two renderers share the camera, the particles and their
// sizes, but not the sprite's profile or lighting, so the test compares where particles are drawn
// (a coverage mask), where the picture's weight lies, and how bright it is.
const kMinCoverageIoU = 0.8;      // intersection over union of the covered pixels
const kMaxCentroidShift = 0.01;   // of the image width
const kMaxCoverageRatio = 1.25;   // covered pixels, web / native, either way
const kMaxMeanColorError = 16;    // mean |web - native| of R, G and B (of 255) where both cover
// Streaks (the sparks preset): the mean coherence of the image's local structure tensors.
const kMinStreakCoherence = 0.4;
const kMaxCoherenceError = 0.1;
let roundCoherence = NaN;
// Self-shadowing (the smoke preset): the page's image against the native one unshadowed, at
// least this many times as far (mean colour error) as against the native shadowed one.
const kMinShadowContrast = 4;         // the debug preset's round sprites, measured on the way
// The liquid and the smoke over the ground grid, the whole image against the native one: the mean
// of each pixel's largest channel error, and the share of pixels off by more than 48/255.
const kMaxWholeImageError = 6;
const kMaxFarPixels = 0.02;
// The smoke's shadow on the ground: how much darker than the bare ground, against the native.
const kMaxGroundShadowError = 0.25;

// How much the image's edges run one way locally: the structure tensor of the luminance's
// gradient, summed over 5 x 5 windows, gives (l1 - l2) / (l1 + l2) at each pixel (0 for a round
// sprite's edge seen whole, 1 for a straight one); the mean over the image weighs each by its
// window's gradient energy.
function streakCoherence({ width, height, data }) {
  const lum = new Float32Array(width * height);
  for (let p = 0; p < lum.length; ++p) lum[p] = 0.3 * data[4 * p] + 0.59 * data[4 * p + 1] + 0.11 * data[4 * p + 2];
  const xx = new Float32Array(lum.length), yy = new Float32Array(lum.length), xy = new Float32Array(lum.length);
  for (let y = 1; y < height - 1; ++y) {
    for (let x = 1; x < width - 1; ++x) {
      const p = y * width + x, gx = (lum[p + 1] - lum[p - 1]) / 2, gy = (lum[p + width] - lum[p - width]) / 2;
      xx[p] = gx * gx; yy[p] = gy * gy; xy[p] = gx * gy;
    }
  }
  let num = 0, den = 0;
  for (let y = 2; y < height - 2; y += 2) {
    for (let x = 2; x < width - 2; x += 2) {
      let a = 0, b = 0, c = 0;
      for (let dy = -2; dy <= 2; ++dy) {
        for (let dx = -2; dx <= 2; ++dx) {
          const q = (y + dy) * width + x + dx;
          a += xx[q]; b += yy[q]; c += xy[q];
        }
      }
      const trace = a + b;
      if (trace <= 0) continue;
      num += Math.sqrt((a - b) * (a - b) + 4 * c * c);
      den += trace;
    }
  }
  return den > 0 ? num / den : 0;
}

const browser = await launch(env.WEB_SITE);
const failures = [];
function check(name, fn) {
  return fn().then(() => console.log(`ok   ${name}`), (e) => {
    failures.push(name);
    console.log(`FAIL ${name}: ${e.stack || e}`);
  });
}

// `prepare(page)` runs before the page loads (a browser made to lack an extension, say).
async function open(clipUrl, extra = '', prepare = null) {
  const page = await browser.newPage();
  if (prepare) await prepare(page);
  page.on('pageerror', (e) => console.log(`  page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error' && !/favicon|404/.test(m.text())) console.log(`  console: ${m.text()}`); });
  await page.goto(`${site}?url=${encodeURIComponent(clipUrl)}${extra}`, { timeout: 120000 });
  return page;
}

// Every cached frame shown, and at least 60 images (the clip's 48 frames, interpolated, looping).
const playedALoop = () => {
  const s = window.player.state;
  return s.error || (s.meta && s.distinctShown === s.meta.frames && s.shown >= 60);
};
const waitFor = (page, fn, timeout, arg) => page.waitForFunction(fn, { timeout, polling: 50 }, arg);
const playerState = (page) => page.evaluate(() => {
  const s = window.player.state;
  return { error: s.error, shown: s.shown, distinct: s.distinctShown, frames: s.meta && s.meta.frames,
    retries: s.cache && s.cache.retries, requests: s.cache && s.cache.requests, stalls: s.stalls,
    buffersMade: s.buffersMade,
    timing: s.timing, count: s.count };
});

// Chooses `look` in the page's look menu and waits for the banner that refuses it: the banner, the
// player's error state, and the look the menu and the address are on after.
async function chooseRefusedLook(page, look) {
  await page.select('#look', look);
  await waitFor(page, () => !document.getElementById('error').hidden, 30000);
  return page.evaluate(() => ({ banner: document.getElementById('error').textContent,
    error: window.player.state.error, look: document.getElementById('look').value,
    preset: new URLSearchParams(location.search).get('preset') }));
}

// The canvas's pixels as RGBA rows (the drawing buffer is preserved).
function canvasPixels(page) {
  return page.evaluate(() => {
    const c = document.getElementById('view');
    const copy = document.createElement('canvas');
    copy.width = c.width; copy.height = c.height;
    const ctx = copy.getContext('2d');
    ctx.drawImage(c, 0, 0);
    return { width: c.width, height: c.height, data: Array.from(ctx.getImageData(0, 0, c.width, c.height).data) };
  });
}

// Pixels that differ from the image's background (its most common colour) by more than 24/255.
function coverage({ width, height, data }) {
  const counts = new Map();
  for (let i = 0; i < data.length; i += 4) {
    const key = (data[i] >> 3) << 10 | (data[i + 1] >> 3) << 5 | (data[i + 2] >> 3);
    counts.set(key, (counts.get(key) || 0) + 1);
  }
  const bg = [...counts.entries()].sort((a, b) => b[1] - a[1])[0][0];
  const b = [(bg >> 10) * 8 + 4, ((bg >> 5) & 31) * 8 + 4, (bg & 31) * 8 + 4];
  const mask = new Uint8Array(width * height);
  let n = 0, cx = 0, cy = 0;
  for (let p = 0; p < width * height; ++p) {
    const d = Math.max(Math.abs(data[4 * p] - b[0]), Math.abs(data[4 * p + 1] - b[1]), Math.abs(data[4 * p + 2] - b[2]));
    if (d > 24) { mask[p] = 1; n++; cx += p % width; cy += Math.floor(p / width); }
  }
  return { mask, n, cx: cx / Math.max(n, 1), cy: cy / Math.max(n, 1), width, height };
}

async function nativeImage(page, file) {
  return page.evaluate(async (url) => {
    const img = new Image();
    img.src = url;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.width; c.height = img.height;
    const ctx = c.getContext('2d');
    ctx.drawImage(img, 0, 0);
    return { width: img.width, height: img.height, data: Array.from(ctx.getImageData(0, 0, img.width, img.height).data) };
  }, `${base}${file}`);
}

async function recordsEqualNative(page) {
  const got = await page.evaluate(async (f) => {
    const r = await window.player.records(f);
    return { count: r.count, bytes: Array.from(r.bytes) };
  }, frame);
  const want = fs.readFileSync(env.WEB_REFERENCE);
  assert.equal(got.bytes.length, want.length, `frame ${frame}: ${got.bytes.length} bytes decoded, native ${want.length}`);
  let differ = 0;
  for (let i = 0; i < want.length; ++i) if (got.bytes[i] !== want[i]) differ++;
  assert.equal(differ, 0, `frame ${frame}: ${differ} of ${want.length} bytes differ from the native decode`);
  return got.count;
}

// The page's image against a native PNG: the coverage masks (web, native), their intersection over
// union, the centroids' distance (a fraction of the width), the covered pixels' ratio (>= 1) and
// the mean colour error where both cover.
async function againstNative(page, png) {
  const webPixels = await canvasPixels(page);
  const nativePixels = await nativeImage(page, png);
  const web = coverage(webPixels), native = coverage(nativePixels);
  assert.equal(web.width, native.width);
  let inter = 0, union = 0;
  for (let p = 0; p < web.mask.length; ++p) { inter += web.mask[p] & native.mask[p]; union += web.mask[p] | native.mask[p]; }
  const iou = inter / Math.max(union, 1);
  const shift = Math.hypot(web.cx - native.cx, web.cy - native.cy) / web.width;
  const ratio = Math.max(web.n / native.n, native.n / web.n);
  let colorError = 0;
  for (let p = 0; p < web.mask.length; ++p) {
    if (!(web.mask[p] & native.mask[p])) continue;
    for (let c = 0; c < 3; ++c) colorError += Math.abs(webPixels.data[4 * p + c] - nativePixels.data[4 * p + c]);
  }
  colorError /= 3 * Math.max(inter, 1);
  return { webPixels, nativePixels, web, native, iou, shift, ratio, colorError };
}

// The whole image, the backdrop's sky and grid included, as the native one: the mean of each
// pixel's largest channel error, and the share of pixels off by more than 48/255.
function wholeImageAsNative(web, native) {
  let sum = 0, far = 0;
  for (let p = 0; p < web.data.length; p += 4) {
    let d = 0;
    for (let c = 0; c < 3; ++c) d = Math.max(d, Math.abs(web.data[p + c] - native.data[p + c]));
    sum += d;
    if (d > 48) far++;
  }
  const n = web.data.length / 4, mean = sum / n;
  console.log(`  whole image: mean largest channel error ${mean.toFixed(2)}/255 (<= ${kMaxWholeImageError}), ` +
    `${(100 * far / n).toFixed(2)}% of the pixels off by more than 48 (<= ${kMaxFarPixels * 100}%)`);
  assert.ok(mean <= kMaxWholeImageError, `whole-image error ${mean}`);
  assert.ok(far <= kMaxFarPixels * n, `${far} pixels off by more than 48`);
}

// A shadow on the ground as the native renderer casts it: where the native image is darker than
// the native image without the shadow (`bare`) by more than 8/255, outside `exclude` (a mask, or
// null), the page's is darker than `bare` by about as much.
function groundShadowAsNative(web, native, bare, exclude) {
  const darker = (img, p) => (bare.data[4 * p] + bare.data[4 * p + 1] + bare.data[4 * p + 2] -
    img.data[4 * p] - img.data[4 * p + 1] - img.data[4 * p + 2]) / 3;
  let n = 0, nativeDark = 0, webDark = 0;
  for (let p = 0; p < web.data.length / 4; ++p) {
    if ((exclude && exclude[p]) || darker(native, p) <= 8) continue;
    n++;
    nativeDark += darker(native, p);
    webDark += darker(web, p);
  }
  nativeDark /= Math.max(n, 1);
  webDark /= Math.max(n, 1);
  console.log(`  the shadow on the ground: ${n} pixels, darker than without it by ${webDark.toFixed(1)}/255 ` +
    `(native ${nativeDark.toFixed(1)}; within ${kMaxGroundShadowError * 100}%)`);
  assert.ok(n >= 200, `${n} pixels of shadow on the native ground`);
  assert.ok(Math.abs(webDark - nativeDark) <= kMaxGroundShadowError * nativeDark, `ground darker by ${webDark}, native ${nativeDark}`);
}

// A path relative to the page (index.html?url=CLIP takes either).
const relativeClip = path.relative(env.WEB_SITE, env.WEB_CLIP);

if (mode === 'playback') {
  // At a quarter of real time. Between two images the player's clock moves on by one tick of the
  // page, so a browser that draws fewer than 24 images a second skips cached frames at speed 1,
  // and showing every one of them then waits on the phase drifting: under load on 2 cores that
  // once took longer than this check's 60 s. At 0.25 a cached frame lasts 167 ms of the page's
  // time, and every one is shown while the page draws 6 images a second or more.
  const page = await open(relativeClip, '&size=480x270&speed=0.25');
  await check('plays every frame (60 images or more) from a relative URL, looping', async () => {
    await waitFor(page, playedALoop, 60000);
    const s = await playerState(page);
    assert.equal(s.error, null);
    assert.ok(s.distinct === s.frames, `showed ${s.distinct} distinct frames of ${s.frames}`);
    // The particles travel in two buffers handed back and forth, made once: none per image.
    assert.ok(s.buffersMade <= 2, `${s.buffersMade} particle buffers made for ${s.shown} images`);
    console.log(`  ${s.shown} frames shown (${s.distinct} distinct), ${s.requests} requests, ${s.stalls} stalls, ` +
      `${s.buffersMade} particle buffers made; ` +
      `last frame ${s.count} particles: decode ${s.timing.decodeMs.toFixed(2)} ms, sort ${s.timing.sortMs.toFixed(2)} ms, ` +
      `draw ${s.timing.drawMs.toFixed(2)} ms`);
  });
  await check(`the canvas is not blank (frame ${frame})`, async () => {
    // A known frame, not wherever the loop stands: the clip's first frames hold a particle or two.
    await page.evaluate((f) => window.player.show(f), frame);
    const c = coverage(await canvasPixels(page));
    assert.ok(c.n >= 100, `${c.n} of ${c.width * c.height} pixels differ from the background (a blank canvas: 0)`);
    console.log(`  ${c.n} of ${c.width * c.height} pixels drawn`);
  });
  await check(`frame ${frame}'s decoded records equal the native decoder's`, async () => {
    const count = await recordsEqualNative(page);
    console.log(`  ${count} particles, every byte equal`);
  });
  await page.close();

  // Played backwards, each image between two cached frames. The browser's decoder cannot save its
  // state on the way, so a step back past the frames it kept decodes from the keyframe again; the
  // frames kept from that walk (up to 8) then serve the next steps without decoding. Decoding from
  // the keyframe at every step cost the sparks 1,126 decodes here (one group of 48 frames; 135 with the frames kept).
  const back = await open(relativeClip, "&size=320x180&frame=999");
  await check('plays backwards, decoding at most 3 frames a step, and the frames kept are exact', async () => {
    await waitFor(back, () => window.player.state.error || window.player.state.shown >= 1, 30000);
    const frames = (await playerState(back)).frames;
    const before = await back.evaluate(() => window.player.state.framesDecoded);
    let exact = 0;
    for (let f = frames - 2; f >= 0; --f) {
      await back.evaluate((at) => window.player.show(at), f + 0.5);
      const s = await back.evaluate(() => ({ frame: window.player.state.frame, error: window.player.state.error }));
      assert.equal(s.error, null);
      assert.equal(s.frame, f, `showed frame ${s.frame} for ${f + 0.5}`);
      if (f === frame) exact = await recordsEqualNative(back);  // frame 30: kept since the walk to 32
    }
    const decoded = (await back.evaluate(() => window.player.state.framesDecoded)) - before;
    const steps = frames - 1;
    console.log(`  ${steps} steps back: ${decoded} frames decoded (${(decoded / steps).toFixed(2)} a step); ` +
      `frame ${frame}'s ${exact} particles equal the native decode`);
    assert.ok(exact > 0, `frame ${frame} held no particles`);
    assert.ok(decoded <= 3 * steps, `${decoded} frames decoded for ${steps} steps back`);
  });
  await back.close();

  // The looks, each against the native renderer's image of the same frame and camera: the debug
  // preset (flat stored colours), the sparks (additive, streaked along their motion, bloom) and the
  // default sprites coloured by speed (lit, tone-mapped).
  const sparks = { clip: env.WEB_CLIP, frame, camera: env.WEB_CAMERA };
  const flip = { clip: env.WEB_FLIP_CLIP, frame: 40, camera: env.WEB_FLIP_CAMERA };
  for (const [name, extra, png, checkMore, shot = sparks] of [
    ['the debug preset', '&preset=debug', env.WEB_NATIVE_PNG, null],
    ['the sparks preset', '&preset=sparks', env.WEB_NATIVE_SPARKS_PNG, (web, native) => {
      // Streaks: the sprites' edges line up along their motion. Round sprites score about
      // kRoundCoherence here (the debug image); the native sparks well above it.
      const w = streakCoherence(web), n = streakCoherence(native);
      console.log(`  streak coherence web ${w.toFixed(3)}, native ${n.toFixed(3)} (round sprites ` +
        `${roundCoherence.toFixed(3)}; >= ${kMinStreakCoherence} and within ${kMaxCoherenceError} of native)`);
      assert.ok(w >= kMinStreakCoherence, `streak coherence ${w}: the sparks are not streaked`);
      assert.ok(Math.abs(w - n) <= kMaxCoherenceError, `streak coherence ${w} against native ${n}`);
    }],
    ['colour by speed', '&color-by=speed&ramp=fire&ramp-range=0,4', env.WEB_NATIVE_SPEED_PNG, (web, native, mask) => {
      // Not black: the ramp's colours (fire: red to yellow), where particles are drawn.
      let sum = [0, 0, 0], n = 0;
      for (let p = 0; p < mask.length; ++p) {
        if (!mask[p]) continue;
        for (let c = 0; c < 3; ++c) sum[c] += web.data[4 * p + c];
        n++;
      }
      // Black sprites would hardly differ from the background (5, 6, 9): few pixels would count.
      const mean = sum.map((v) => v / Math.max(n, 1));
      console.log(`  ${n} pixels drawn, of mean colour (${mean.map((v) => v.toFixed(0)).join(', ')})`);
      assert.ok(n >= 500, `${n} pixels drawn: black sprites?`);
      assert.ok(mean[0] >= 40 && mean[0] > mean[2] * 1.5, `mean colour ${mean}: not the fire ramp's reds and yellows`);
    }],
    ['colour by an attribute (age)', '&ramp-attribute=age&ramp=viridis&ramp-range=0,1.5', env.WEB_NATIVE_AGE_PNG, (web, native, mask) => {
      // The ramp's two ends both drawn: young sparks purple-blue (blue over green), old ones
      // green (green over blue).
      let young = 0, old = 0, n = 0;
      for (let p = 0; p < mask.length; ++p) {
        if (!mask[p]) continue;
        n++;
        if (web.data[4 * p + 2] > web.data[4 * p + 1]) young++;
        else old++;
      }
      console.log(`  ${n} pixels drawn: ${young} bluer (young), ${old} greener (old)`);
      assert.ok(young >= 0.05 * n && old >= 0.05 * n, `${young} young and ${old} old of ${n}: one end of the ramp only`);
    }, { clip: env.WEB_AGE_CLIP, frame, camera: env.WEB_AGE_CAMERA }],
    ['the smoke preset (self-shadowed) on the FLIP pour', '&preset=smoke&backdrop=none', env.WEB_NATIVE_SMOKE_PNG, async (web, native, mask, page) => {
      // The shadows are there: the image is far nearer the native shadowed one than the native
      // image of the same sprites unshadowed (`--opacity 0.55`, the preset without its shadows).
      const unshadowed = await nativeImage(page, env.WEB_NATIVE_UNSHADOWED_PNG);
      const error = (other) => {
        let sum = 0, n = 0;
        for (let p = 0; p < mask.length; ++p) {
          if (!mask[p]) continue;
          for (let c = 0; c < 3; ++c) sum += Math.abs(web.data[4 * p + c] - other.data[4 * p + c]);
          n += 3;
        }
        return sum / Math.max(n, 1);
      };
      const shadowed = error(native), plain = error(unshadowed);
      console.log(`  mean colour error where the page draws: ${shadowed.toFixed(2)}/255 against the native ` +
        `shadowed image, ${plain.toFixed(2)}/255 against it unshadowed (>= ${kMinShadowContrast}x as far)`);
      assert.ok(plain >= kMinShadowContrast * shadowed, `shadowed ${shadowed}, unshadowed ${plain}: no self-shadowing?`);
    }, flip],
    // The liquid's surface (LiquidPass's passes, the filter as a fragment pass) on the plain
    // background, then over the ground grid it refracts and reflects the sky over.
    ['the liquid on the FLIP pour', '&preset=liquid&backdrop=none', env.WEB_NATIVE_LIQUID_NONE_PNG, null, flip],
    // A sprite image (`texture=`, as `--texture`), upright as natively: the ring's colours are
    // green above and red below, so one drawn upside down misses the mean colour error.
    ['a sprite image (texture=)', `&preset=debug&texture=${env.WEB_TEXTURE}`, env.WEB_NATIVE_TEXTURE_PNG, null,
      { clip: env.WEB_FLIP_CLIP, frame: 40, camera: env.WEB_TEXTURE_CAMERA }],
    // With its shadow on the ground: where the native image is darker than the native one without
    // the shadow (`--liquid-shadow-depth 0`), under the liquid too (it refracts the shadow).
    ['the liquid over the ground grid, with its shadow', '&preset=liquid', env.WEB_NATIVE_LIQUID_PNG, async (web, native, mask, page) => {
      wholeImageAsNative(web, native);
      groundShadowAsNative(web, native, await nativeImage(page, env.WEB_NATIVE_LIQUID_BARE_PNG), null);
    }, flip],
    // The smoke over the ground (backdrop "auto"), with the shadow its slices cast on it: on the
    // ground outside the smoke (as the native image without a backdrop covers it), against the
    // bare ground (`--opacity 0`).
    ['the smoke preset over the ground, shadowed', '&preset=smoke', env.WEB_NATIVE_SMOKE_GROUND_PNG, async (web, native, mask, page) => {
      wholeImageAsNative(web, native);
      groundShadowAsNative(web, native, await nativeImage(page, env.WEB_NATIVE_GROUND_PNG),
        coverage(await nativeImage(page, env.WEB_NATIVE_SMOKE_PNG)).mask);
    }, flip]
  ]) {
    const still = await open(shot.clip, `&size=480x270&frame=${shot.frame}&camera=${shot.camera}${extra}`);
    await check(`frame ${shot.frame}'s image matches the native renderer's (same camera), ${name}`, async () => {
      await waitFor(still, () => window.player.state.error || window.player.state.shown >= 1, 30000);
      assert.equal((await playerState(still)).error, null);
      await still.evaluate((f) => window.player.show(f), shot.frame);
      const { webPixels, nativePixels, web, native, iou, shift, ratio, colorError } = await againstNative(still, png);
      console.log(`  coverage IoU ${iou.toFixed(3)} (>= ${kMinCoverageIoU}), centroid shift ${(shift * 100).toFixed(2)}% ` +
        `of the width (<= ${kMaxCentroidShift * 100}%), covered pixels web ${web.n} / native ${native.n}, ` +
        `mean colour error ${colorError.toFixed(1)}/255 where both cover (<= ${kMaxMeanColorError})`);
      // web_frame_sparks, _speed, _age, _smoke, _liquid_none, _liquid, _smoke_ground
      const look = extra.split('=')[1].split('&')[0], plain = extra.includes('backdrop=none');
      const file = name === 'the debug preset' ? 'web_frame.png'
        : `web_frame_${look}${look === 'liquid' && plain ? '_none' : look === 'smoke' && !plain ? '_ground' : ''}.png`;
      await still.screenshot({ path: path.join(env.WEB_OUT, file) });
      if (name === 'the debug preset') roundCoherence = streakCoherence(webPixels);
      assert.ok(iou >= kMinCoverageIoU, `coverage IoU ${iou}`);
      assert.ok(shift <= kMaxCentroidShift, `centroid shift ${shift}`);
      assert.ok(ratio <= kMaxCoverageRatio, `coverage ratio ${ratio}`);
      assert.ok(colorError <= kMaxMeanColorError, `mean colour error ${colorError}`);
      if (checkMore) await checkMore(webPixels, nativePixels, web.mask, still);
    });
    await still.close();
  }

  // A ramp without a range spans the first image's speeds (0 to their 99th percentile): the
  // sparks come out in the fire ramp's colours, not black.
  const auto = await open(env.WEB_CLIP, `&size=480x270&frame=${frame}&camera=${env.WEB_CAMERA}&color-by=speed&ramp=fire`);
  await check('colour by speed without a range: the ramp spans the first image', async () => {
    await waitFor(auto, () => window.player.state.error || window.player.state.shown >= 1, 30000);
    assert.equal((await playerState(auto)).error, null);
    const pixels = await canvasPixels(auto), c = coverage(pixels);
    let red = 0, blue = 0;
    for (let p = 0; p < c.mask.length; ++p) if (c.mask[p]) { red += pixels.data[4 * p]; blue += pixels.data[4 * p + 2]; }
    red /= Math.max(c.n, 1);
    blue /= Math.max(c.n, 1);
    console.log(`  ${c.n} pixels drawn, mean red ${red.toFixed(0)}, blue ${blue.toFixed(0)}`);
    assert.ok(c.n >= 500 && red >= 40 && red > 1.5 * blue, `${c.n} pixels, red ${red}, blue ${blue}`);
  });
  await auto.close();

  // The look menu: sprites to sparks on the page, as the native sparks; on a clip without
  // velocities the sparks are refused with the library's message, and the look before stays.
  const menu = await open(env.WEB_CLIP, `&size=480x270&frame=${frame}&camera=${env.WEB_CAMERA}`);
  await check('the look menu turns the sprites into the native sparks', async () => {
    await waitFor(menu, () => window.player.state.error || window.player.state.shown >= 1, 30000);
    await menu.select('#look', 'sparks');
    await waitFor(menu, () => new URLSearchParams(location.search).get('preset') === 'sparks', 30000);
    await menu.evaluate((f) => window.player.show(f), frame);
    const r = await againstNative(menu, env.WEB_NATIVE_SPARKS_PNG);
    console.log(`  against the native sparks: IoU ${r.iou.toFixed(3)}, colour error ${r.colorError.toFixed(1)}/255`);
    assert.ok(r.iou >= kMinCoverageIoU && r.colorError <= kMaxMeanColorError, `IoU ${r.iou}, colour error ${r.colorError}`);
  });
  await menu.close();
  const refused = await open(env.WEB_EMPTY_CLIP, '&size=320x180');
  await check('the look menu refuses sparks on a clip without velocities, and plays on', async () => {
    await waitFor(refused, () => window.player.state.error || window.player.state.shown >= 1, 30000);
    const s = await chooseRefusedLook(refused, 'sparks');
    assert.match(s.banner, /motion blur \(a shutter\) needs velocities/);
    assert.equal(s.error, null);
    assert.equal(s.look, 'sprites');
    assert.equal(s.preset, null);
    console.log(`  ${s.banner}`);
  });
  await refused.close();

  // A browser without one of the liquid's float extensions (phones' GPUs often have no
  // OES_texture_float_linear): the look menu refuses the liquid with a message naming it, and the
  // look before (the sparks, whose particles travel with their velocities) stays, in the page and
  // in the worker (the same image again, every pixel); a page asked for the liquid says so.
  const lacksFloatLinear = (page) => page.evaluateOnNewDocument(() => {
    const get = WebGL2RenderingContext.prototype.getExtension;
    WebGL2RenderingContext.prototype.getExtension = function (name) {
      return name === 'OES_texture_float_linear' ? null : get.call(this, name);
    };
  });
  const lacksMessage = /the liquid needs WebGL2's OES_texture_float_linear, which this browser lacks/;
  const phone = await open(env.WEB_CLIP, `&size=480x270&frame=${frame}&camera=${env.WEB_CAMERA}&preset=sparks`,
    lacksFloatLinear);
  await check('without a float extension the look menu refuses the liquid, and the look before stays', async () => {
    await waitFor(phone, () => window.player.state.error || window.player.state.shown >= 1, 30000);
    assert.equal((await playerState(phone)).error, null);
    const before = await canvasPixels(phone);
    const s = await chooseRefusedLook(phone, 'liquid');
    assert.match(s.banner, lacksMessage);
    assert.equal(s.error, null);
    assert.equal(s.look, 'sparks');
    assert.equal(s.preset, 'sparks');
    const shown = (await playerState(phone)).shown;
    await phone.evaluate((f) => window.player.show(f), frame);
    const after = await canvasPixels(phone), state = await playerState(phone);
    assert.equal(state.error, null);
    assert.ok(state.shown > shown, 'no image drawn after the refusal');
    let differ = 0;
    for (let i = 0; i < after.data.length; ++i) differ += after.data[i] !== before.data[i];
    assert.equal(differ, 0, `${differ} channels differ from the image before the refusal`);
    console.log(`  ${s.banner}; the sparks' image again, every pixel`);
  });
  await phone.close();
  const phoneLiquid = await open(env.WEB_FLIP_CLIP, '&size=320x180&preset=liquid', lacksFloatLinear);
  await check('without a float extension preset=liquid is refused with a message', async () => {
    await waitFor(phoneLiquid, () => window.player.state.error, 30000);
    const s = await playerState(phoneLiquid);
    assert.match(s.error, lacksMessage);
    console.log(`  ${s.error}`);
  });
  await phoneLiquid.close();

  // A look the browser cannot draw, or one the clip lacks what for, is refused with the library's message.
  for (const [extra, expect] of [
    ['&texture=missing_sprite.png', /texture=missing_sprite\.png: HTTP 404/],
    ['&backdrop=grund', /backdrop 'grund': expected auto, ground, sky or none \(did you mean 'ground'\?\)/],
    ['&preset=spark', /look preset 'spark'.*did you mean 'sparks'/],
    ['&color-by=speed', /colouring by speed needs velocities, and the clip has none: cook it again with `--attributes velocity`/]
  ]) {
    const clip = extra === '&color-by=speed' ? env.WEB_EMPTY_CLIP : env.WEB_CLIP;
    const page = await open(clip, `&size=320x180${extra}`);
    await check(`${extra.slice(1)} is refused with a message`, async () => {
      await waitFor(page, () => window.player.state.error, 30000);
      const s = await playerState(page);
      assert.match(s.error, expect);
      console.log(`  ${s.error}`);
    });
    await page.close();
  }

  // A valid clip whose frames hold no particles plays (nothing to draw), with no error.
  const empty = await open(env.WEB_EMPTY_CLIP, '&size=320x180');
  await check('a clip of empty frames plays without an error', async () => {
    await waitFor(empty, () => window.player.state.error || window.player.state.shown >= 3, 30000);
    const s = await playerState(empty);
    assert.equal(s.error, null);
    assert.equal(s.count, 0);
    const c = coverage(await canvasPixels(empty));
    assert.equal(c.n, 0, `${c.n} pixels drawn for a clip of no particles`);
    console.log(`  ${s.shown} images of ${s.frames} empty frames`);
  });
  await empty.close();
} else if (mode === 'faults') {
  const clip = env.WEB_CLIP;
  await check('50 ms latency and 503s: retried, played, and the frames are exact', async () => {
    const page = await open(`${base}/~latency=50/~fail=503x3${clip}`, '&size=320x180');
    await waitFor(page, playedALoop, 90000);
    const s = await playerState(page);
    assert.equal(s.error, null);
    assert.ok(s.retries >= 1, `${s.retries} retries`);
    await recordsEqualNative(page);
    console.log(`  ${s.shown} frames shown, ${s.requests} requests, ${s.retries} retries, ${s.stalls} stalls`);
    await page.close();
  });
  for (const [name, prefix, expect] of [
    ['a file replaced on the server', '/~change=2', /changed on the server/],
    ['500 on every request', '/~fail=500x1000', /HTTP 500, after 5 attempts/],
    ['a missing file', '/~fail=503x0', /HTTP 404/]
  ]) {
    await check(`${name} ends in an error on the page, and the tab answers`, async () => {
      const url = name === 'a missing file' ? `${base}${prefix}${clip}.missing` : `${base}${prefix}${clip}`;
      const page = await open(url, '&size=320x180');
      const started = Date.now();
      await waitFor(page, () => window.player.state.error, 30000);
      const s = await playerState(page);
      assert.match(s.error, expect);
      assert.ok(s.error.includes(clip), `the message names the URL: ${s.error}`);
      const banner = await page.$eval('#error', (e) => (e.hidden ? '' : e.textContent));
      assert.equal(banner, s.error);
      // The main thread still runs: a click is handled at once.
      const label = await page.evaluate(() => { document.getElementById('play').click(); return document.getElementById('play').textContent; });
      assert.ok(label === 'Play' || label === 'Pause');
      console.log(`  after ${((Date.now() - started) / 1000).toFixed(1)} s: ${s.error}`);
      await page.close();
    });
  }
} else {
  console.error(`player_test.mjs: expected playback or faults, got ${mode}`);
  process.exitCode = 2;
}

await browser.close();
if (failures.length) {
  console.log(`${failures.length} failed: ${failures.join('; ')}`);
  process.exitCode = 1;
}
