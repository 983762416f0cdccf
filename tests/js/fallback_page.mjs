// What the fallback pages share (fallback_babylon.html, fallback_playcanvas.html, fallback_model_viewer.html,
// volume_scatter_babylon.html; fallback.html takes aimLight): fetch ?config=NAME.json, draw, and hand the
// result back the way tests/browser.py waits for it.
export async function run(draw) {
  try {
    const config = await (await fetch(new URLSearchParams(location.search).get('config'))).json();
    window.sssbakeResult = await draw(config);
    window.sssbakeReady = true;
  } catch (e) {
    window.sssbakeError = String(e && e.stack || e);
  }
}

// A three.js DirectionalLight (any copy of three: model-viewer bundles its own) placed as verify's
// light: from `centre` towards the unit `towards`, at twice the bounding `radius`, of irradiance
// `exposure`, its shadow map spanning the drawn meshes.
export function aimLight(light, centre, radius, towards, exposure) {
  const Vector3 = light.position.constructor;
  light.position.copy(centre).addScaledVector(new Vector3(...towards), 2 * radius);
  light.target.position.copy(centre);
  light.intensity = exposure;
  light.castShadow = true;
  const r = radius * 1.01;
  Object.assign(light.shadow.camera, { left: -r, right: r, top: r, bottom: -r, near: 0.5 * r, far: 3.5 * r });
  light.shadow.camera.updateProjectionMatrix();
  light.shadow.mapSize.set(2048, 2048);
  light.shadow.normalBias = 0.01 * radius;
}
