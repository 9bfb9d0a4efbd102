// Drives the web player's benchmark mode (index.html?bench=1) in headless Chromium for one clip and
// prints its figures as JSON. Run by bench/web/run.sh under tests/http/with_server.sh.
//   node bench.mjs SITE_DIR CLIP
import path from 'node:path';
import { createRequire } from 'node:module';

const [site, clip] = process.argv.slice(2);
const require = createRequire(path.join(site, '../../web/package.json'));
const puppeteer = require('puppeteer-core');
const base = process.env.PSTREAM_TEST_URL_BASE;
const browser = await puppeteer.launch({
  executablePath: '/usr/bin/chromium', headless: true,
  args: ['--headless=new', '--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--disable-dev-shm-usage']
});
try {
  const page = await browser.newPage();
  await page.goto(`${base}${site}/index.html?url=${encodeURIComponent(clip)}&size=1280x720&bench=1`);
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
