// Screenshot a page in headless Chromium once it says it is ready (tests/browser.py drives this).
// usage: node screenshot.mjs URL OUT.png WIDTH HEIGHT READY_EXPRESSION TIMEOUT_MS CHROMIUM
import puppeteer from 'puppeteer-core';

const [url, out, width, height, ready, timeoutMs, executablePath] = process.argv.slice(2);
const browser = await puppeteer.launch({
  executablePath,
  headless: true,
  // WebGL 2 on the CPU through SwiftShader; no background networking on machines with none.
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
    '--no-first-run', '--disable-background-networking', '--disable-component-update', '--disable-sync',
    '--disable-quic', `--window-size=${width},${height}`],
});
const logs = [];
try {
  const page = await browser.newPage();
  page.on('console', (m) => logs.push(`console.${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => logs.push(`pageerror: ${e.message}`));
  await page.setViewport({ width: Number(width), height: Number(height), deviceScaleFactor: 1 });
  await page.goto(url, { waitUntil: 'load', timeout: Number(timeoutMs) });
  await page.waitForFunction(`(${ready}) || window.sssbakeError !== undefined`, { timeout: Number(timeoutMs), polling: 100 });
  const error = await page.evaluate(() => window.sssbakeError);
  if (error !== undefined) {
    console.log(JSON.stringify({ error: String(error), logs }));
    process.exitCode = 3;
  } else {
    await page.screenshot({ path: out, type: 'png' });
    const result = await page.evaluate(() => window.sssbakeResult ?? null);
    console.log(JSON.stringify({ result, logs }));
  }
} catch (e) {
  console.log(JSON.stringify({ error: `screenshot: ${e.message}`, logs }));
  process.exitCode = 4;
} finally {
  await browser.close();
}
