// Renders each job of ?jobs=URL with the three.js runtime and hands the linear images back
// (window.sssbakeResult: per job {images: {mode: base64 float32 RGBA, row 0 at the bottom}} or
// {error}); a load the plugin refuses is a job's result, not a page error. A job's `options` go to
// createRuntime; with `stock`, images.stock is the same file loaded by a GLTFLoader without the
// plugin and drawn by three itself (MeshPhysicalMaterial, a DirectionalLight) into a float target
// in the same page, renderer, camera and light.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { SSSBakePlugin, createRuntime } from '/runtime_three/sssbake-three.js';

const SHADERS = '/runtime_shaders/';

function base64(floats) {
  const bytes = new Uint8Array(floats.buffer, floats.byteOffset, floats.byteLength);
  let text = '';
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(text);
}

/** `url` as three alone draws it: linear float RGBA, row 0 at the bottom. */
async function stock(renderer, url, camera, towardsLight, size) {
  const gltf = await new GLTFLoader().loadAsync(url);
  const sun = new THREE.DirectionalLight(0xffffff, 1);
  sun.position.copy(towardsLight).normalize();
  gltf.scene.add(sun, sun.target);
  const target = new THREE.WebGLRenderTarget(size, size, { type: THREE.FloatType });
  renderer.setRenderTarget(target);
  renderer.setClearColor(0x000000, 0);
  renderer.clear();
  renderer.render(gltf.scene, camera);
  const out = new Float32Array(size * size * 4);
  renderer.readRenderTargetPixels(target, 0, 0, size, size, out);
  renderer.setRenderTarget(null);
  target.dispose();
  return out;
}

async function run() {
  const { size, jobs } = await (await fetch(new URLSearchParams(location.search).get('jobs'))).json();
  const renderer = new THREE.WebGLRenderer({ canvas: document.getElementById('view'), antialias: false });
  renderer.setPixelRatio(1);
  renderer.setSize(size, size, false);
  const results = [];
  for (const job of jobs) {
    const loader = new GLTFLoader();
    loader.register((parser) => new SSSBakePlugin(parser, { shaderBase: SHADERS, source: job.glb }));
    let gltf;
    try {
      gltf = await loader.loadAsync(job.glb);
    } catch (error) {
      results.push({ error: error.message, kind: error.name });
      continue;
    }
    const runtime = await createRuntime(renderer, gltf.scene, gltf, { shaderBase: SHADERS, srgb: false, ...(job.options || {}) });
    const c = job.camera;
    const camera = new THREE.PerspectiveCamera(c.fov, 1, c.near, c.far);
    camera.position.set(...c.eye);
    camera.lookAt(new THREE.Vector3(...c.target));
    camera.updateProjectionMatrix();
    runtime.setLight({ direction: new THREE.Vector3(...job.light), intensity: 1 });
    const images = {};
    const ms = {};
    for (const mode of job.modes) {
      runtime.setMode(mode);
      const t = performance.now();
      runtime.render(camera);
      images[mode] = base64(runtime.readLinear());
      ms[mode] = performance.now() - t;
    }
    runtime.dispose();
    if (job.stock) images.stock = base64(await stock(renderer, job.glb, camera, new THREE.Vector3(...job.light), size));
    results.push({ techniques: runtime.techniques, images, ms });
  }
  window.sssbakeResult = results;
  window.sssbakeReady = true;
}

run().catch((error) => { window.sssbakeError = `${error.name}: ${error.message}`; });
