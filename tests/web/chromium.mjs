// Debian's Chromium, headless, driven by puppeteer-core from web/node_modules (web/package-lock.json):
// the one way the web player's test and benchmark start a browser (docs/web.md). WebGL2 runs on
// SwiftShader; as root, Chromium needs --no-sandbox.
import path from 'node:path';
import { createRequire } from 'node:module';

export function launch(site) {
  const require = createRequire(path.join(site, '../../web/package.json'));
  const puppeteer = require('puppeteer-core');
  return puppeteer.launch({
    executablePath: '/usr/bin/chromium',
    headless: true,
    // A whole benchmark of a 1M-particle clip on SwiftShader waits in one call for many minutes.
    protocolTimeout: 30 * 60 * 1000,
    // The suite's other tests share the machine's two cores: a start may take long there.
    timeout: 120 * 1000,
    args: ['--headless=new', '--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
      '--disable-gpu-sandbox', '--disable-dev-shm-usage']
  });
}
