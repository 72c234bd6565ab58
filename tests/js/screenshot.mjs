// A picture of the viewer for the README: `node tests/js/screenshot.mjs <file.strata> <out.png>`
// serves the file with `strata serve`, opens the viewer in headless Chromium at 1280×800,
// refines to 1 px and writes a screenshot of the page.

import { spawn } from 'node:child_process';
import { createRequire } from 'node:module';
import { strataBin } from './helpers.mjs';

const [file, out] = process.argv.slice(2);
if (!file || !out) throw new Error('usage: node tests/js/screenshot.mjs <file.strata> <out.png>');
const { chromium } = createRequire(import.meta.url)('playwright-core');
const server = spawn(strataBin(), ['serve', file, '--port', '0'], { stdio: ['ignore', 'pipe', 'inherit'] });
const url = await new Promise((resolve) => server.stdout.on('data', (d) => /open (\S+)/.test(d) && resolve(/open (\S+)/.exec(d)[1])));
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--disable-background-networking'],
});
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  await page.goto(url);
  await page.evaluate(() => window.strata.ready());
  await page.evaluate(() => window.strata.setLimits({ pixelError: 1 }));
  await page.evaluate(() => window.strata.idle());
  await page.screenshot({ path: out });
  console.log(`${out}: ${JSON.stringify(await page.evaluate(() => {
    const s = window.strata.state();
    return { nodes: s.drawn.length, requests: s.requests, bytesRead: s.bytesRead, fileLength: s.fileLength, firstFrameMs: s.firstFrameMs, textureBytesRead: s.textureBytesRead };
  }))}`);
} finally {
  await browser.close();
  server.kill();
}
