// Drives the web player's benchmark mode (index.html?bench=1) in headless Chromium for one clip and
// prints its figures as JSON. Run by bench/web/run.sh under tests/http/with_server.sh.
//   node bench.mjs SITE_DIR CLIP [PRESET]     (PRESET: the page's look, default debug)
import { launch } from '../../tests/web/chromium.mjs';

const [site, clip, preset = 'debug'] = process.argv.slice(2);
const base = process.env.PSTREAM_TEST_URL_BASE;
const browser = await launch(site);
try {
  const page = await browser.newPage();
  await page.goto(`${base}${site}/index.html?url=${encodeURIComponent(clip)}&size=1280x720&preset=${preset}&bench=1`);
  await page.waitForFunction(() => window.player.bench || window.player.state.error, { timeout: 600000, polling: 200 });
  const result = await page.evaluate(() => ({ bench: window.player.bench, error: window.player.state.error,
    renderer: (() => {
      const gl = document.getElementById('view').getContext('webgl2');
      const info = gl.getExtension('WEBGL_debug_renderer_info');
      return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
    })() }));
  if (result.error) throw new Error(result.error);
  console.log(JSON.stringify({ ...result.bench, renderer: result.renderer }));
} finally {
  await browser.close();
}
