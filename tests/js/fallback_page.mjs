// What the fallback pages of other engines share (fallback_babylon.html, fallback_playcanvas.html):
// fetch ?config=NAME.json, draw, and hand the result back the way tests/browser.py waits for it.
export async function run(draw) {
  try {
    const config = await (await fetch(new URLSearchParams(location.search).get('config'))).json();
    window.sssbakeResult = await draw(config);
    window.sssbakeReady = true;
  } catch (e) {
    window.sssbakeError = String(e && e.stack || e);
  }
}
