// Drives `sssbake view`'s page with real input (tests/view/test_view_page.py): a plain drag, a
// shift-drag and a click on the 'plain' button, printing the page's state after each as JSON.
// usage: node interact.mjs URL CHROMIUM
import puppeteer from 'puppeteer-core';

const [url, executablePath] = process.argv.slice(2);
const browser = await puppeteer.launch({
  executablePath,
  headless: true,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
    '--no-first-run', '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
const logs = [];
try {
  const page = await browser.newPage();
  page.on('pageerror', (e) => logs.push(`pageerror: ${e.message}`));
  await page.setViewport({ width: 320, height: 240, deviceScaleFactor: 1 });
  await page.goto(url, { waitUntil: 'load', timeout: 120000 });
  await page.waitForFunction('window.sssbakeReady === true || window.sssbakeError !== undefined', { timeout: 120000 });
  const state = () => page.evaluate(() => window.sssbakeError ?? window.sssbakeViewer.state);
  const drag = async (dx, dy) => {
    // from the canvas' lower right, clear of the panel
    await page.mouse.move(240, 180);
    await page.mouse.down();
    for (let i = 1; i <= 8; i++) await page.mouse.move(240 + (dx * i) / 8, 180 + (dy * i) / 8);
    await page.mouse.up();
  };
  const states = { start: await state() };
  await drag(60, 0);
  states.orbited = await state();
  await page.keyboard.down('Shift');
  await drag(60, -40);
  await page.keyboard.up('Shift');
  states.lightMoved = await state();
  await page.click('button[data-mode=plain]');
  states.plain = await state();
  console.log(JSON.stringify({ states, logs }));
} catch (e) {
  console.log(JSON.stringify({ error: e.message, logs }));
} finally {
  await browser.close();
}
