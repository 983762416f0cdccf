// sssbake view: load /model.glb through the sssbake GLTFLoader plugin, draw it with the runtime, and
// let the user orbit, move the light and switch between the baked techniques, the standard
// fallback material and a plain one. window.sssbakeViewer is the page's API (tests drive it);
// window.sssbakeReady turns true after the first frame, window.sssbakeError holds a failure.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { SSSBakePlugin, createRuntime } from '/runtime_three/sssbake-three.js';

const shaderBase = new URL('/runtime_shaders/', location.href).href;
const canvas = document.getElementById('view');
const errorLine = document.getElementById('error');
const azimuth = document.getElementById('azimuth');
const elevation = document.getElementById('elevation');

function fail(error) {
  // one line: the plugin's refusal of a stale file names the file, the table and the tool
  const message = String(error?.message ?? error).split('\n')[0];
  errorLine.textContent = message;
  document.getElementById('panel').hidden = true;
  window.sssbakeError = message;
}
window.addEventListener('unhandledrejection', (e) => fail(e.reason));
window.addEventListener('error', (e) => fail(e.error ?? e.message));

function lightDirection() {
  // world direction towards the light, +y up, azimuth 0 towards +z
  const az = THREE.MathUtils.degToRad(Number(azimuth.value));
  const el = THREE.MathUtils.degToRad(Number(elevation.value));
  return new THREE.Vector3(Math.cos(el) * Math.sin(az), Math.sin(el), Math.cos(el) * Math.cos(az));
}

async function load() {
  // fetched here rather than by the loader so that errors can name the user's file (the server
  // sends its name), not /model.glb
  const response = await fetch('/model.glb');
  if (!response.ok) throw new Error(`cannot load the model: HTTP ${response.status}`);
  const disposition = response.headers.get('Content-Disposition') || '';
  const name = decodeURIComponent((disposition.match(/filename\*=UTF-8''([^;]+)/) || [null, 'model.glb'])[1]);
  document.title = `${name} · sssbake view`;
  const loader = new GLTFLoader();
  loader.register((parser) => new SSSBakePlugin(parser, { shaderBase, source: name }));
  return loader.parseAsync(await response.arrayBuffer(), '/');
}

async function main() {
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  // the runtime's targets take the drawing buffer's size when it is made: size it first
  renderer.setSize(canvas.clientWidth, canvas.clientHeight, false);
  const gltf = await load();
  const scene = gltf.scene;
  let runtime = await createRuntime(renderer, scene, gltf, { shaderBase });
  const modes = [...runtime.techniques, 'fallback', 'plain'];

  // frame the model: its bounding sphere fills ~80% of the height
  const camera = new THREE.PerspectiveCamera(35, canvas.clientWidth / canvas.clientHeight);
  const sphere = new THREE.Box3().setFromObject(scene).getBoundingSphere(new THREE.Sphere());
  const distance = (sphere.radius / Math.sin(THREE.MathUtils.degToRad(camera.fov) / 2)) * 1.25;
  camera.near = distance / 100;
  camera.far = distance * 100;
  camera.position.copy(sphere.center).add(new THREE.Vector3(0, 0, distance));
  camera.updateProjectionMatrix();
  const controls = new OrbitControls(camera, canvas);
  controls.target.copy(sphere.center);
  controls.update();

  const params = new URLSearchParams(location.search);
  let mode = modes.includes(params.get('mode')) ? params.get('mode') : modes[0];

  function draw() {
    runtime.setMode(mode);
    runtime.setLight({ direction: lightDirection(), color: new THREE.Color(1, 1, 1), intensity: 1 });
    runtime.render(camera);
  }
  let pending = false;
  function redraw() {
    if (!pending) {
      pending = true;
      requestAnimationFrame(() => { pending = false; draw(); });
    }
  }

  const buttons = new Map();
  function setMode(name) {
    if (!modes.includes(name)) throw new Error(`no mode ${name}; this file has ${modes.join(', ')}`);
    mode = name;
    for (const [m, b] of buttons) b.setAttribute('aria-pressed', String(m === name));
    redraw();
  }
  for (const m of modes) {
    const b = document.createElement('button');
    b.textContent = m;
    b.dataset.mode = m;
    b.title = runtime.techniques.includes(m) ? `sssbake's ${m} technique`
      : m === 'fallback' ? "the file's standard glTF material, as a stock viewer shows it"
        : 'Lambert, no scattering';
    b.addEventListener('click', () => setMode(m));
    buttons.set(m, b);
    document.getElementById('modes').append(b);
  }

  // shift-drag moves the light; a capturing listener sees the pointer before OrbitControls does
  let lightDrag = null;
  canvas.addEventListener('pointerdown', (e) => {
    if (!e.shiftKey) return;
    controls.enabled = false;
    lightDrag = { x: e.clientX, y: e.clientY, az: Number(azimuth.value), el: Number(elevation.value) };
    canvas.setPointerCapture(e.pointerId);
  }, { capture: true });
  canvas.addEventListener('pointermove', (e) => {
    if (!lightDrag) return;
    const az = lightDrag.az + (e.clientX - lightDrag.x) * 0.5;
    azimuth.value = String((((az + 180) % 360) + 360) % 360 - 180);
    elevation.value = String(THREE.MathUtils.clamp(lightDrag.el - (e.clientY - lightDrag.y) * 0.5, -89, 89));
    redraw();
  });
  canvas.addEventListener('pointerup', () => { lightDrag = null; controls.enabled = true; });
  azimuth.addEventListener('input', redraw);
  elevation.addEventListener('input', redraw);
  controls.addEventListener('change', redraw);

  // a new size needs new runtime targets: rebuild it once the window stops changing, one rebuild
  // at a time, and keep drawing with the old runtime until the new one is ready
  let resizing = null;
  let rebuilding = Promise.resolve();
  let rebuilds = 0;
  window.addEventListener('resize', () => {
    clearTimeout(resizing);
    resizing = setTimeout(() => {
      rebuilding = rebuilding.then(async () => {
        renderer.setSize(canvas.clientWidth, canvas.clientHeight, false);
        camera.aspect = canvas.clientWidth / canvas.clientHeight;
        camera.updateProjectionMatrix();
        const next = await createRuntime(renderer, scene, gltf, { shaderBase });
        runtime.dispose();
        runtime = next;
        rebuilds += 1;
        redraw();
      }).catch(fail);
    }, 150);
  });

  function capture(width) {
    // the frame just drawn, scaled to `width` pixels across, read in the same task (before the
    // browser presents and clears the drawing buffer): {width, height, rgb: bytes, row 0 at the top}
    const small = document.createElement('canvas');
    small.width = width;
    small.height = Math.max(1, Math.round((width * canvas.height) / canvas.width));
    const context = small.getContext('2d');
    context.drawImage(canvas, 0, 0, small.width, small.height);
    const rgba = context.getImageData(0, 0, small.width, small.height).data;
    const rgb = Array.from({ length: (rgba.length / 4) * 3 }, (_, i) => rgba[Math.floor(i / 3) * 4 + (i % 3)]);
    return { width: small.width, height: small.height, rgb };
  }

  window.sssbakeViewer = {
    modes,
    get mode() { return mode; },
    /** What the user set: {mode, light: [azimuth, elevation] degrees, camera: [x, y, z] world},
     * and how often a resize rebuilt the runtime. */
    get state() {
      return {
        mode, light: [Number(azimuth.value), Number(elevation.value)], camera: camera.position.toArray(), rebuilds,
      };
    },
    setMode,
    /** Light from azimuth (degrees about +y, 0 towards +z) and elevation (degrees above the xz plane). */
    setLight(azimuthDegrees, elevationDegrees) {
      azimuth.value = String(azimuthDegrees);
      elevation.value = String(elevationDegrees);
      redraw();
    },
    /** Every mode drawn now, {mode: {width, height, rgb}} at `width` pixels across; then the
     * current mode again. */
    frames(width = 64) {
      const current = mode;
      const out = {};
      for (const m of modes) {
        mode = m;
        draw();
        out[m] = capture(width);
      }
      mode = current;
      draw();
      return out;
    },
  };

  setMode(mode);
  document.getElementById('panel').hidden = false;
  draw();
  requestAnimationFrame(() => { window.sssbakeReady = true; });
}

main().catch(fail);
