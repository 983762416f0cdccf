// sssbake's three.js runtime: a GLTFLoader plugin that reads the SSSBAKE_subsurface extension
// (tables found by name and checked: count, type, componentType, CRC-32) and a runtime that draws
// prt, spectral and screen with the same GLSL files as sssbake's moderngl runtime
// (runtime_shaders/), plus the standard fallback (the file's own materials) and a plain shader.
//
//   import { SSSBakePlugin, createRuntime } from './runtime_three/sssbake-three.js';
//   const loader = new GLTFLoader();
//   loader.register((parser) => new SSSBakePlugin(parser, { shaderBase, source: url }));
//   const gltf = await loader.loadAsync(url);
//   const runtime = await createRuntime(renderer, gltf.scene, gltf, { shaderBase });
//   runtime.setMode('prt'); runtime.setLight({ direction, color, intensity }); runtime.render(camera);
//
// `three` and `three/addons/...` come from the page's import map.
import * as THREE from 'three';

import { crc32Hex, ENCODINGS, EXTENSION, likelyTool } from './sssbake-format.mjs';

export { EXTENSION };

const SCHEMA_MAJOR = 2;
/** Width of the wrapped 2-D layout of long tables (pipeline/render/renderer.py TABLE_WIDTH). */
const TABLE_WIDTH = 4096;
/** Shadow lookups move this many shadow texels off the surface (gl_passes.SHADOW_OFFSET_TEXELS). */
const SHADOW_OFFSET_TEXELS = 1.5;
/** Precision lines of the essl300 dialect (pipeline/render/shaders.py); three adds #version. */
const ESSL_PRELUDE = 'precision highp float;\nprecision highp int;\nprecision highp sampler2D;\n'
  + 'precision highp isampler2D;\nprecision highp usampler2D;\n';
const INCLUDE = /^[ \t]*#include[ \t]+"([^"]+)"[ \t]*$/gm;
const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4, MAT2: 4, MAT3: 9, MAT4: 16 };
const ARRAYS = { 5120: Int8Array, 5121: Uint8Array, 5122: Int16Array, 5123: Uint16Array, 5125: Uint32Array, 5126: Float32Array };
/** Screen runtime defaults (pipeline/techniques/screen/runtime.py ScreenRuntimeOptions). */
const SCREEN_DEFAULTS = { jacobian: true, fill: true, interleave: 4, resolve: true };
/** This runtime's addition to screen (off: the moderngl runtime's passes exactly): light through
 * thin parts, from the file's fallback (screen_surface.frag, SSS_TRANSMISSION). */
const SCREEN_TRANSMISSION = true;
/** three's names of the TEXCOORD_n attributes, by Texture.channel. */
const UV_ATTRIBUTES = ['uv', 'uv1', 'uv2', 'uv3'];
/** Length of the shader's SH coefficient arrays: SH_MAX_ORDER² (sh_basis.glsl). */
const SH_MAX_TERMS = 64;
export const MODES = ['prt', 'spectral', 'screen', 'fallback', 'plain'];

/** A file whose sssbake data cannot be used (stale after another tool, or too old). */
export class SSSBakeDataError extends Error {
  constructor(message) {
    super(message);
    this.name = 'SSSBakeDataError';
  }
}

// ---------------------------------------------------------------------------------------------
// Reading the extension

/** The keys of a table reference, all required (exporters/gltf_tables.py REFERENCE_KEYS). */
const REFERENCE_KEYS = ['accessor', 'componentType', 'count', 'crc32', 'name', 'type'];

function isTableReference(value) {
  return value !== null && typeof value === 'object' && !Array.isArray(value) && 'accessor' in value;
}

/** An accessor's elements packed densely (count x components, no stride) in its component type. */
function denseArray(attribute, componentType) {
  const Type = ARRAYS[componentType];
  if (!attribute.isInterleavedBufferAttribute) return attribute.array;
  const out = new Type(attribute.count * attribute.itemSize);
  const data = attribute.data.array;
  for (let i = 0; i < attribute.count; i++) {
    for (let c = 0; c < attribute.itemSize; c++) out[i * attribute.itemSize + c] = data[i * attribute.data.stride + attribute.offset + c];
  }
  return out;
}

export class SSSBakePlugin {
  /**
   * @param {GLTFParser} parser
   * @param {{shaderBase?: string, source?: string}} options  `shaderBase`: URL of runtime_shaders/, for
   *   createRuntime; `source` names the file in errors.
   */
  constructor(parser, options = {}) {
    this.name = EXTENSION;
    this.parser = parser;
    this.options = options;
    this.source = options.source || 'the glTF file';
  }

  fail(message) {
    throw new SSSBakeDataError(`${this.source}: ${message}`);
  }

  /** Refuses stale data (the wording of exporters/gltf_tables.py SssbakeGltf.stale). */
  stale(problem) {
    const json = this.parser.json;
    const generator = String((json.asset && json.asset.generator) || '');
    this.fail(`${problem}; likely broken by ${likelyTool(generator)} (asset.generator '${generator}'): bake the asset `
      + `again, or process the file only with tools that keep the ${EXTENSION} extension`);
  }

  async beforeRoot() {
    const json = this.parser.json;
    if (json.extras && json.extras.sssbake && !(json.extensions && json.extensions[EXTENSION])) {
      this.fail('written by sssbake schema 1.x (extras.sssbake); rebake it with this version');
    }
    const root = json.extensions && json.extensions[EXTENSION];
    if (!root) {
      const custom = new Set((json.meshes || []).flatMap((m) => m.primitives.flatMap((p) => Object.keys(p.attributes))));
      const ours = [...custom].filter((n) => n.startsWith('_SSS_') || n.startsWith('_THICKNESS')).sort();
      if (ours.length) this.stale(`sssbake vertex attributes ${ours.join(', ')} without the root's ${EXTENSION} object`);
    }
    if (root && parseInt(String(root.schemaVersion), 10) !== SCHEMA_MAJOR) {
      this.fail(`${EXTENSION} schemaVersion '${root.schemaVersion}': this runtime reads ${SCHEMA_MAJOR}.x; `
        + 'rebake it with this version');
    }
  }

  /** Table reference `ref` (at JSON path `where`) resolved by the contract's rule and checked, as
   * {name, array (dense, component type), itemSize, count}. */
  async table(ref, where) {
    const accessors = this.parser.json.accessors || [];
    if (Object.keys(ref).sort().join() !== REFERENCE_KEYS.join()) {
      this.stale(`${where} is not a table reference {${REFERENCE_KEYS.join(', ')}}: ${JSON.stringify(ref)}`);
    }
    const table = `sssbake table '${ref.name}' (${where})`;
    let index = ref.accessor;
    if (!(accessors[index] && accessors[index].name === ref.name)) {
      const named = accessors.flatMap((a, i) => (a.name === ref.name ? [i] : []));
      if (named.length !== 1) this.stale(`${table}: ${named.length ? `${named.length} accessors ([${named}])` : 'no accessor'} bears its name`);
      index = named[0];
    }
    const def = accessors[index];
    for (const key of ['count', 'type', 'componentType']) {
      if (def[key] !== ref[key]) this.stale(`${table}: accessor ${index} has ${key} ${def[key]}, the reference ${ref[key]}`);
    }
    const attribute = await this.parser.getDependency('accessor', index);
    const array = denseArray(attribute, def.componentType);
    const crc = crc32Hex(new Uint8Array(array.buffer, array.byteOffset, array.byteLength));
    if (crc !== ref.crc32) this.stale(`${table}: accessor ${index}'s data has CRC-32 ${crc}, the reference ${ref.crc32}`);
    return { name: ref.name, array, itemSize: COMPONENTS[def.type], count: def.count };
  }

  /** `block` (at JSON path `where`) with every table reference replaced by its resolved table (deep). */
  async resolve(block, where) {
    if (isTableReference(block)) return this.table(block, where);
    if (Array.isArray(block)) return Promise.all(block.map((v, i) => this.resolve(v, `${where}[${i}]`)));
    if (block !== null && typeof block === 'object') {
      const entries = await Promise.all(Object.entries(block).map(async ([k, v]) => [k, await this.resolve(v, `${where}.${k}`)]));
      return Object.fromEntries(entries);
    }
    return block;
  }

  /** Checks a primitive's geometry against the bake: its vertex count and each vertex attribute the
   * mesh block lists (`attributeTypes`) with the root's declared encoding. */
  checkPrimitive(mesh, meshIndex, primitive, block, declared) {
    const json = this.parser.json;
    const count = mesh.geometry.attributes.position.count;
    const expected = block.vertexCounts && block.vertexCounts[primitive];
    const where = `mesh ${meshIndex} primitive ${primitive}`;
    if (expected !== undefined && expected !== count) this.stale(`${where} has ${count} vertices, baked with ${expected}`);
    const attributes = json.meshes[meshIndex].primitives[primitive].attributes;
    for (const [name, type] of Object.entries(block.attributeTypes || {})) {
      const index = attributes[name];
      if (index === undefined) this.stale(`${where} lacks vertex attribute ${name}`);
      const def = json.accessors[index];
      const decl = declared.get(name);
      if (!decl || !ENCODINGS[decl.encoding]) this.stale(`${where}: attribute ${name} is not declared in the root's ${EXTENSION}.attributes`);
      const [componentType, normalized] = ENCODINGS[decl.encoding];
      if (def.count !== count || def.type !== type || def.componentType !== componentType || !!def.normalized !== normalized) {
        this.stale(`${where}: attribute ${name} is componentType ${def.componentType}, normalized ${!!def.normalized}, `
          + `${def.type} x ${def.count}; declared ${componentType}, ${normalized}, ${type} x ${count} (POSITION)`);
      }
    }
  }

  async afterRoot(result) {
    const json = this.parser.json;
    const root = json.extensions && json.extensions[EXTENSION];
    if (!root) return;
    const block = (owner, kind, i) => this.resolve(owner.extensions && owner.extensions[EXTENSION], `${kind}[${i}].extensions.${EXTENSION}`);
    const meshBlocks = await Promise.all((json.meshes || []).map((m, i) => block(m, 'meshes', i)));
    const materialBlocks = await Promise.all((json.materials || []).map((m, i) => block(m, 'materials', i)));
    const declared = new Map((root.attributes || []).map((a) => [a.name, a]));
    result.userData.sssbake = { root, meshes: meshBlocks, materials: materialBlocks, shaderBase: this.options.shaderBase };
    const scenes = result.scenes && result.scenes.length ? result.scenes : [result.scene];
    for (const scene of scenes) {
      scene.traverse((object) => {
        const at = object.isMesh ? this.parser.associations.get(object) : undefined;
        if (!at || at.meshes === undefined) return;
        const primitive = at.primitives === undefined ? 0 : at.primitives;
        const block = meshBlocks[at.meshes];
        const materialIndex = json.meshes[at.meshes].primitives[primitive].material;
        const materialBlock = materialIndex === undefined ? undefined : materialBlocks[materialIndex];
        if (!block && !materialBlock) return;
        if (block) this.checkPrimitive(object, at.meshes, primitive, block, declared);
        const techniques = {};
        if (block && block.prt) techniques.prt = block.prt;
        // spectral without its tables is the subsurface normal attribute alone
        const normal = [...declared.values()].find((a) => a.key === 'sss:normal');
        const primitiveAttributes = json.meshes[at.meshes].primitives[primitive].attributes;
        if (block && block.spectral) techniques.spectral = block.spectral;
        else if (normal && primitiveAttributes[normal.name] !== undefined) techniques.spectral = { attributes: { normal: normal.name } };
        if (block && (block.scaleMm !== undefined) && materialBlock && materialBlock.screen) techniques.screen = materialBlock.screen;
        object.userData.sssbake = {
          mesh: at.meshes, primitive, scaleMm: block ? block.scaleMm : undefined,
          material: materialBlock && materialBlock.material, techniques,
        };
      });
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Shaders

/** Fetches runtime_shaders/ files and inlines #include like pipeline/render/shaders.py. */
class ShaderLibrary {
  constructor(base) {
    this.base = base.endsWith('/') ? base : `${base}/`;
    this.files = new Map();
  }

  async text(name) {
    if (!this.files.has(name)) {
      this.files.set(name, fetch(this.base + name).then((r) => {
        if (!r.ok) throw new Error(`sssbake: shader ${name}: HTTP ${r.status} from ${this.base}`);
        return r.text();
      }));
    }
    return this.files.get(name);
  }

  async expand(name, seen = new Set()) {
    if (seen.has(name)) return '';
    seen.add(name);
    const text = await this.text(name);
    const parts = [];
    let last = 0;
    for (const m of text.matchAll(INCLUDE)) {
      parts.push(text.slice(last, m.index), await this.expand(m[1], seen));
      last = m.index + m[0].length;
    }
    parts.push(text.slice(last));
    return parts.join('');
  }

  /** GLSL ES 3.00 source of `name` after `prelude` (#defines), without the #version line. */
  async source(name, prelude = '') {
    return ESSL_PRELUDE + prelude + (await this.expand(name));
  }
}

/** The `in` variables of a vertex shader source and whether each is an integer type. */
function shaderInputs(source) {
  const inputs = new Map();
  for (const m of source.matchAll(/^\s*in\s+(\w+)\s+(\w+)\s*;/gm)) inputs.set(m[2], /^(u?int|[iu]vec\d)$/.test(m[1]));
  return inputs;
}

function rawMaterial(vertexShader, fragmentShader, uniforms, extra = {}) {
  return new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3, vertexShader, fragmentShader, uniforms, side: THREE.DoubleSide, ...extra,
  });
}

/** A geometry whose attributes carry the shader's input names (`sources`: name -> attribute),
 * integer inputs bound as integers (vertexAttribIPointer) whatever the stored type. */
function programGeometry(geometry, vertexSource, sources) {
  const inputs = shaderInputs(vertexSource);
  const out = new THREE.BufferGeometry();
  out.setIndex(geometry.index);
  for (const [name, attribute] of Object.entries(sources)) {
    if (!inputs.has(name)) throw new Error(`sssbake: the vertex shader declares no input ${name}`);
    if (!attribute) throw new Error(`sssbake: no vertex data for shader input ${name}`);
    out.setAttribute(name, inputs.get(name) ? integerAttribute(attribute) : attribute);
  }
  // three culls by the bounding sphere, which it would compute from `position`, absent here
  if (!geometry.boundingSphere) geometry.computeBoundingSphere();
  out.boundingSphere = geometry.boundingSphere;
  return out;
}

/** The stored integers of an attribute (a normalized one's raw codes; floats rounded) for an
 * integer shader input. */
function integerAttribute(attribute) {
  const array = attribute.array;
  const values = array instanceof Float32Array ? Int32Array.from(array, Math.round) : array;
  const out = new THREE.BufferAttribute(values, attribute.itemSize);
  out.gpuType = THREE.IntType;
  return out;
}

// ---------------------------------------------------------------------------------------------
// Tables as textures

const INTEGER_FORMATS = {
  1: [THREE.RedIntegerFormat, 'R'], 2: [THREE.RGIntegerFormat, 'RG'], 4: [THREE.RGBAIntegerFormat, 'RGBA'],
};

/**
 * Rows (m x components) laid out row-major in a (width, ceil(m / width)) texture, as
 * gl_passes.table_texture does; `kind` 'f32', 'i32', 'u8', 'i8'.
 */
function tableTexture(rows, components, kind, width) {
  const m = Math.max(1, Math.ceil(rows.length / components));
  const w = Math.min(width, m);
  const h = Math.ceil(m / w);
  const Type = { f32: Float32Array, i32: Int32Array, u8: Uint8Array, i8: Int8Array }[kind];
  const data = new Type(w * h * components);
  data.set(rows);
  let texture;
  if (kind === 'f32') {
    texture = new THREE.DataTexture(data, w, h, components === 4 ? THREE.RGBAFormat : THREE.RedFormat, THREE.FloatType);
  } else {
    const [format, prefix] = INTEGER_FORMATS[components];
    const type = { i32: THREE.IntType, u8: THREE.UnsignedByteType, i8: THREE.ByteType }[kind];
    texture = new THREE.DataTexture(data, w, h, format, type);
    texture.internalFormat = `${prefix}${{ i32: '32I', u8: '8UI', i8: '8I' }[kind]}`;
  }
  texture.minFilter = texture.magFilter = THREE.NearestFilter;
  texture.generateMipmaps = false;
  texture.unpackAlignment = 1;
  texture.needsUpdate = true;
  return texture;
}

/** `table.array` (count x itemSize) widened to 4 components of typed array `Type`. */
function pad4(table, Type, itemSize = table ? table.itemSize : 1) {
  if (!table) return new Type(4);
  const n = table.array.length / itemSize;
  const out = new Type(Math.max(n, 1) * 4);
  for (let i = 0; i < n; i++) for (let c = 0; c < itemSize; c++) out[4 * i + c] = table.array[i * itemSize + c];
  return out;
}

/** prt tables and per-vertex codes as the uniforms of prt_decode.glsl (prt/runtime.py `upload`). */
function prtUniforms(prt, geometry, width) {
  const k = prt.directionCount;
  const channels = prt.tableChannels;
  const refs = prt.referencePointCount;
  const detailOrder = prt.detailOrder || 0;
  const d = detailOrder * detailOrder;
  const order = prt.shOrder;
  const c = order * order;
  let refCodes;
  if (!refs) refCodes = tableTexture(new Uint8Array(1), 1, 'u8', width);
  else if (channels === 1) refCodes = tableTexture(prt.refCodes.array, 1, 'u8', width);
  else refCodes = tableTexture(pad4(prt.refCodes, Uint8Array, 3), 4, 'u8', width);
  // per reference point its D + 3 detail codes, zero-padded to whole RGBA8I texels
  const rowTexels = Math.ceil((d + 3) / 4);
  const detail = new Int8Array(Math.max(refs * rowTexels, 1) * 4);
  if (d) for (let r = 0; r < refs; r++) detail.set(prt.refDetail.array.subarray(r * (d + 3), (r + 1) * (d + 3)), r * rowTexels * 4);
  // Δq codes of each vertex, 3C channel-major (c * C + i), from _SSS_PRT_DQ<i>: the R, G, B codes of
  // SH coefficient i (prt/layout.py)
  const n = geometry.attributes.position.count;
  const dq = new Int32Array(Math.max(n * 3 * c, 1));
  prt.attributes.dq.forEach((name, i) => {
    const a = geometry.attributes[name.toLowerCase()];
    for (let v = 0; v < n; v++) for (let ch = 0; ch < 3; ch++) dq[v * 3 * c + ch * c + i] = Math.round(a.array[v * a.itemSize + ch]);
  });
  const size = prt.lookupSize;
  // dqScale is stored (C, 3) (its transpose); the shader wants [c * C + i]
  const dqScale = new Float32Array(3 * SH_MAX_TERMS);
  for (let ch = 0; ch < 3; ch++) for (let i = 0; i < c; i++) dqScale[ch * c + i] = prt.dqScale.array[i * 3 + ch];
  const detailScale = new Float32Array(SH_MAX_TERMS);
  if (d) detailScale.set(prt.detailScale.array);
  return {
    u_prt_ref_codes: { value: refCodes },
    u_prt_ref_scale: { value: tableTexture(pad4(prt.refScale, Float32Array), 4, 'f32', width) },
    u_prt_ref_tris: { value: tableTexture(pad4(prt.refTriangles, Int32Array), 4, 'i32', width) },
    u_prt_lut: { value: tableTexture(pad4(prt.lut, Float32Array), 4, 'f32', 256) },
    u_prt_dir_tris: { value: tableTexture(pad4(prt.directionTriangles, Int32Array), 4, 'i32', width) },
    u_prt_dir_neigh: { value: tableTexture(pad4(prt.directionNeighbours, Int32Array), 4, 'i32', width) },
    u_prt_dir_inv: { value: tableTexture(pad4(prt.directionInverse, Float32Array), 4, 'f32', width) },
    u_prt_dq: { value: tableTexture(dq, 1, 'i32', width) },
    u_prt_detail: { value: tableTexture(detail, 4, 'i8', width) },
    u_prt_dir_lookup: { value: tableTexture(prt.directionLookup.array, 1, 'i32', size) },  // L x L
    u_prt_k: { value: k },
    u_prt_refs: { value: refs },
    u_prt_ref_channels: { value: channels },
    u_prt_order: { value: order },
    u_prt_detail_order: { value: detailOrder },
    u_prt_weight_scale: { value: prt.weightScale },
    u_prt_lookup_size: { value: size },
    u_prt_dq_scale: { value: dqScale },
    u_prt_detail_scale: { value: detailScale },
  };
}

/** R_d per channel of an Rd table (T x 3) on r = reach t² (screen/data.py table_integral). */
function tableIntegral(table, reach) {
  const t = table.count;
  const out = [0, 0, 0];
  for (let ch = 0; ch < 3; ch++) {
    let sum = 0;
    let previous = 0;
    for (let i = 0; i < t; i++) {
      const x = i / (t - 1);
      const f = table.array[3 * i + ch] * (reach * x * x) * (2 * reach * x);
      if (i > 0) sum += 0.5 * (f + previous) / (t - 1);
      previous = f;
    }
    out[ch] = 2 * Math.PI * sum;
  }
  return new THREE.Vector3(...out);
}

// ---------------------------------------------------------------------------------------------
// The glTF material's maps and screen's transmission

/** The base-colour texture and normal map of three material `material` (GLTFLoader's, the
 * fallback's) as surface_maps_*.glsl takes them: macros, vertex inputs, uniforms. The texture
 * objects are the material's own (sRGB decoding, filtering, KHR_texture_transform as three set
 * them up); a map whose texture coordinates the primitive lacks is left out, as three does. */
function surfaceMaps(material, geometry) {
  const out = { defines: '', sources: {}, uniforms: {}, textures: [] };
  const add = (texture, macro, input, uniforms) => {
    const uv = texture && geometry.attributes[UV_ATTRIBUTES[texture.channel]];
    if (!uv) return;
    texture.updateMatrix();
    out.defines += `#define ${macro}\n`;
    out.sources[input] = uv;
    out.textures.push(texture);
    Object.assign(out.uniforms, uniforms(texture));
  };
  add(material && material.map, 'SSS_ALBEDO_MAP', 'in_albedo_uv',
    (t) => ({ u_albedo_map: { value: t }, u_albedo_uv_transform: { value: t.matrix } }));
  add(material && material.normalMap, 'SSS_NORMAL_MAP', 'in_normal_uv', (t) => ({
    u_normal_map: { value: t }, u_normal_uv_transform: { value: t.matrix }, u_normal_scale: { value: material.normalScale },
  }));
  return out;
}

/** screen_surface.frag's transmission (SSS_TRANSMISSION) from glTF material `def` (JSON) of a
 * primitive with baked thickness `thickness` (mm per vertex, component 0), or null where the file
 * transmits nothing. The bake (pipeline/bake/fallback.py make_fallback) writes the slab
 * transmittance T(d) at the median thickness d into its own extension, `slabTransmittance`, whole:
 * KHR_materials_diffuse_transmission carries it only in part, and KHR_materials_volume's
 * attenuation is the draft scatter extension's extinction when that is on. The diffusion
 * extinction comes from the medium, sigma_tr = sqrt(3 sigma_a (sigma_a + sigma_s')) per mm; d is
 * the median of the thickness the file carries (the bake's is over welded vertices: seam copies
 * aside, the same). */
function transmissionUniforms(def, thickness) {
  const sss = ((def && def.extensions) || {})[EXTENSION] || {};
  const transmit = sss.slabTransmittance;
  if (!transmit || !thickness || !transmit.some((c) => c > 0) || !sss.material) return null;
  const { sigma_a: absorb, sigma_s_prime: scatter } = sss.material;
  const values = Float32Array.from({ length: thickness.count }, (_, i) => thickness.getX(i)).sort();
  const half = values.length >> 1;
  const median = values.length % 2 ? values[half] : 0.5 * (values[half - 1] + values[half]);
  return {
    u_transmittance: { value: new THREE.Vector3(...transmit) },
    u_sigma_tr: { value: new THREE.Vector3(...absorb.map((a, c) => Math.sqrt(3 * a * (a + scatter[c])))) },
    u_median_mm: { value: median },
  };
}

// ---------------------------------------------------------------------------------------------
// Runtime

function floatTarget(width, height, extra = {}) {
  return new THREE.WebGLRenderTarget(width, height, {
    type: THREE.FloatType, format: THREE.RGBAFormat, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter,
    generateMipmaps: false, depthBuffer: true, ...extra,
  });
}

/** A triangle over the whole viewport (fullscreen.vert reads gl_VertexID only; three needs a
 * position attribute to draw). */
function fullscreenMesh(material) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(9), 3));
  const mesh = new THREE.Mesh(geometry, material);
  mesh.frustumCulled = false;
  return mesh;
}

/** World-space bounding sphere of a mesh's positions: the centre and half-diagonal of its box
 * (renderer.py _bounding_sphere). */
function worldSphere(mesh) {
  const world = new THREE.Box3();
  const p = new THREE.Vector3();
  const positions = mesh.geometry.attributes.position;
  for (let i = 0; i < positions.count; i++) world.expandByPoint(p.fromBufferAttribute(positions, i).applyMatrix4(mesh.matrixWorld));
  const centre = world.getCenter(new THREE.Vector3());
  return { centre, radius: Math.max(0.5 * world.max.distanceTo(world.min), 1e-9) };
}

/** View-projection of a directional light's shadow map over a sphere, and the width it spans
 * (renderer.py light_camera). */
function lightCamera(sphere, towardsLight) {
  const radius = sphere.radius * 1.01;
  const forward = towardsLight.clone().normalize().negate();
  const eye = sphere.centre.clone().addScaledVector(forward, -2 * radius);
  const up = Math.abs(forward.y) < 0.9 ? new THREE.Vector3(0, 1, 0) : new THREE.Vector3(0, 0, 1);
  const right = new THREE.Vector3().crossVectors(forward, up).normalize();
  const trueUp = new THREE.Vector3().crossVectors(right, forward);
  const view = new THREE.Matrix4().set(
    right.x, right.y, right.z, -right.dot(eye),
    trueUp.x, trueUp.y, trueUp.z, -trueUp.dot(eye),
    -forward.x, -forward.y, -forward.z, forward.dot(eye),
    0, 0, 0, 1);
  const ortho = new THREE.Matrix4().set(
    1 / radius, 0, 0, 0,
    0, 1 / radius, 0, 0,
    0, 0, -1 / radius, -2,
    0, 0, 0, 1);
  return { viewProjection: ortho.multiply(view), extent: 2 * radius };
}

const DISPLAY_FRAGMENT = `${ESSL_PRELUDE}
uniform sampler2D u_image;
uniform vec3 u_scale;     // exposure times the light's colour
uniform int u_srgb;
out vec4 f_color;
void main() {
  vec4 texel = texelFetch(u_image, ivec2(gl_FragCoord.xy), 0);
  vec3 c = clamp(texel.rgb * u_scale, 0.0, 1.0);
  if (u_srgb == 1) c = mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
  f_color = vec4(c, 1.0);
}`;

/**
 * The sssbake runtime over a loaded glTF (with `SSSBakePlugin` registered).
 *
 * @param {THREE.WebGLRenderer} renderer  WebGL 2.
 * @param {THREE.Object3D} scene  What to draw (usually gltf.scene).
 * @param {object} gltf  GLTFLoader's result.
 * @param {object} options  shaderBase (URL of runtime_shaders/; default the plugin's), exposure (1), srgb (true: encode the
 *   canvas in sRGB), specular (0) and shininess (64) of the surface reflection, shadowSize (2048),
 *   screen ({jacobian, fill, interleave, resolve}), plainAlbedo (default: each material's colour).
 * @returns {Promise<object>} runtime: techniques, mode, setMode, setLight, render, renderLinear, readLinear, dispose.
 */
export async function createRuntime(renderer, scene, gltf, options = {}) {
  if (!renderer.capabilities.isWebGL2) throw new Error('sssbake: the runtime needs WebGL 2');
  const used = (gltf.parser && gltf.parser.json.extensionsUsed) || [];
  if (used.includes(EXTENSION) && !gltf.userData.sssbake) {
    throw new Error(`sssbake: the file uses ${EXTENSION}: register SSSBakePlugin with the GLTFLoader that loaded it`);
  }
  const shaderBase = options.shaderBase || (gltf.userData.sssbake && gltf.userData.sssbake.shaderBase);
  if (!shaderBase) throw new Error('sssbake: createRuntime needs options.shaderBase (URL of runtime_shaders/)');
  const library = new ShaderLibrary(shaderBase);
  const settings = {
    exposure: 1, srgb: true, specular: 0, shininess: 64, shadowSize: 2048, ...options,
    screen: { ...SCREEN_DEFAULTS, transmission: SCREEN_TRANSMISSION, ...(options.screen || {}) },
  };
  const json = (gltf.parser && gltf.parser.json) || {};
  const thicknessName = ((gltf.userData.sssbake && gltf.userData.sssbake.root.attributes) || [])
    .filter((a) => a.key === 'thickness').map((a) => a.name.toLowerCase())[0];
  const width = Math.min(TABLE_WIDTH, renderer.capabilities.maxTextureSize);
  // a mesh without sssbake data draws plain, where only the specular lobe reads eta
  const eta = (mesh) => (mesh.userData.sssbake && mesh.userData.sssbake.material ? mesh.userData.sssbake.material.eta : 1.5);
  scene.updateMatrixWorld(true);

  const [depthOnly, fullscreen, gather, resolve] = await Promise.all(
    ['depth_only.frag', 'fullscreen.vert', 'screen_gather.frag', 'screen_resolve.frag'].map((n) => library.source(n)));

  const light = { direction: new THREE.Vector3(0.4, 0.8, 0.45).normalize(), color: new THREE.Color(1, 1, 1), intensity: 1 };
  // the fallback's three.js light, the same light for the file's own materials
  const sun = new THREE.DirectionalLight(0xffffff, 1);
  sun.visible = false;
  scene.add(sun, sun.target);

  const lightUniforms = () => ({
    u_point_light: { value: 0 }, u_light: { value: new THREE.Vector3() }, u_intensity: { value: 1 },
    u_mm_per_unit: { value: 1 },
  });
  const surfaceUniforms = (mesh, albedo) => ({
    ...lightUniforms(),
    u_model: { value: new THREE.Matrix4() }, u_view_projection: { value: new THREE.Matrix4() },
    u_normal_matrix: { value: new THREE.Matrix3() }, u_world_to_object: { value: new THREE.Matrix3() },
    u_eye: { value: new THREE.Vector3() }, u_eta: { value: eta(mesh) }, u_specular: { value: settings.specular },
    u_shininess: { value: settings.shininess }, u_diffuse: { value: albedo },
  });

  const meshes = [];
  scene.traverse((o) => { if (o.isMesh) meshes.push(o); });
  const techniques = new Set();
  const items = [];
  const shared = new Set();  // the file's own textures, which the fallback still draws with
  for (const mesh of meshes) {
    const data = mesh.userData.sssbake || { techniques: {} };
    const original = mesh.material;
    const color = settings.plainAlbedo ? new THREE.Vector3(...settings.plainAlbedo)
      : original && original.color ? new THREE.Vector3(original.color.r, original.color.g, original.color.b) : new THREE.Vector3(0.8, 0.8, 0.8);
    // glTF lets a primitive omit normals (flat shading); the shaders need one per vertex
    if (!mesh.geometry.attributes.normal) mesh.geometry.computeVertexNormals();
    const attrs = mesh.geometry.attributes;
    // every mode keeps the material's base-colour texture and normal map
    const maps = surfaceMaps(original, mesh.geometry);
    maps.textures.forEach((texture) => shared.add(texture));
    const sources = { in_position: attrs.position, in_normal: attrs.normal, ...maps.sources };
    const surface = (albedo) => ({ ...surfaceUniforms(mesh, albedo), ...maps.uniforms });
    const [plainVert, plainFrag] = await Promise.all(['plain.vert', 'plain.frag'].map((n) => library.source(n, maps.defines)));
    const item = { mesh, original, materials: {}, geometries: {} };
    const plainGeometry = programGeometry(mesh.geometry, plainVert, sources);
    item.materials.plain = rawMaterial(plainVert, plainFrag, surface(color));
    item.geometries.plain = plainGeometry;
    const t = data.techniques;
    if (t.prt) {
      const defines = `#define PRT_SH_ORDER ${t.prt.shOrder}\n#define PRT_DETAIL_ORDER ${t.prt.detailOrder || 0}\n`
        + (t.prt.weightBits === 8 ? '#define PRT_COMPACT\n' : '') + maps.defines;
      const [vertex, prtFrag] = await Promise.all([library.source('prt.vert', defines), library.source('sss_surface.frag', maps.defines)]);
      const prtSources = { ...sources, in_prt_ref: attrs[t.prt.attributes.ref.toLowerCase()] };
      item.geometries.prt = programGeometry(mesh.geometry, vertex, prtSources);
      item.materials.prt = rawMaterial(vertex, prtFrag, { ...surface(new THREE.Vector3()), ...prtUniforms(t.prt, mesh.geometry, width) });
      techniques.add('prt');
    }
    if (t.spectral) {
      const normal = attrs[t.spectral.attributes.normal.toLowerCase()];
      item.geometries.spectral = programGeometry(mesh.geometry, plainVert, { ...sources, in_normal: normal });
      item.materials.spectral = rawMaterial(plainVert, plainFrag, surface(color));
      techniques.add('spectral');
    }
    if (t.screen) {
      const gbuffer = await library.source('screen_gbuffer.frag', maps.defines);
      item.screen = screenPasses(mesh, t.screen, data.scaleMm, plainGeometry, plainVert, gbuffer, maps.uniforms);
      const primitive = json.meshes && json.meshes[data.mesh].primitives[data.primitive];
      const through = settings.screen.transmission && primitive
        ? transmissionUniforms(json.materials[primitive.material], attrs[thicknessName]) : null;
      const defines = maps.defines + (through ? '#define SSS_TRANSMISSION\n' : '');
      const [vertex, fragment] = await Promise.all([library.source('plain.vert', defines), library.source('screen_surface.frag', defines)]);
      item.geometries.screen = through ? programGeometry(mesh.geometry, vertex, { ...sources, in_thickness: attrs[thicknessName] }) : plainGeometry;
      item.materials.screen = rawMaterial(vertex, fragment, {
        ...surface(new THREE.Vector3()), ...through, u_scattered: { value: item.screen.scattered.texture },
      });
      techniques.add('screen');
    }
    items.push(item);
  }

  function screenPasses(mesh, screen, scaleMm, geometry, plainVert, gbuffer, mapUniforms) {
    const size = renderer.getDrawingBufferSize(new THREE.Vector2());
    const count = screen.offsets.count;
    const samples = new Float32Array(4 * count);
    for (let i = 0; i < count; i++) {
      samples.set([screen.offsets.array[2 * i], screen.offsets.array[2 * i + 1], screen.weights.array[i], 0], 4 * i);
    }
    const entries = screen.rdTable.count;
    const rd = pad4(screen.rdTable, Float32Array);
    const shadowTarget = new THREE.WebGLRenderTarget(settings.shadowSize, settings.shadowSize, {
      depthTexture: new THREE.DepthTexture(settings.shadowSize, settings.shadowSize, THREE.FloatType),
    });
    const gbufferTarget = floatTarget(size.x, size.y, { count: 2 });
    const resolving = settings.screen.resolve && settings.screen.interleave > 1;
    const scattered = floatTarget(size.x, size.y, { depthBuffer: false });
    const gathered = resolving ? floatTarget(size.x, size.y, { depthBuffer: false }) : scattered;
    const transforms = () => ({
      u_model: { value: new THREE.Matrix4() }, u_normal_matrix: { value: new THREE.Matrix3() },
      u_view_projection: { value: new THREE.Matrix4() },
    });
    const shadowMaterial = rawMaterial(plainVert, depthOnly, transforms());
    const gbufferMaterial = rawMaterial(plainVert, gbuffer, {
      ...transforms(), ...lightUniforms(), ...mapUniforms, u_eta: { value: eta(mesh) },
      u_light_view_projection: { value: new THREE.Matrix4() }, u_shadow: { value: shadowTarget.depthTexture },
      u_shadow_offset: { value: 0 },
    });
    const sampleTexture = tableTexture(samples, 4, 'f32', count);
    const rdTexture = tableTexture(rd, 4, 'f32', entries);
    const gatherMaterial = rawMaterial(fullscreen, gather, {
      u_position: { value: gbufferTarget.textures[0] }, u_normal: { value: gbufferTarget.textures[1] },
      u_samples: { value: sampleTexture }, u_rd: { value: rdTexture },
      u_view_projection: { value: new THREE.Matrix4() }, u_eye: { value: new THREE.Vector3() },
      u_mm_per_world: { value: 1 }, u_count: { value: count }, u_jacobian: { value: settings.screen.jacobian ? 1 : 0 },
      u_fill: { value: settings.screen.fill ? 1 : 0 }, u_interleave: { value: settings.screen.interleave },
      u_reach_mm: { value: screen.tableReachMm }, u_total: { value: tableIntegral(screen.rdTable, screen.tableReachMm) },
    }, { depthTest: false, depthWrite: false });
    const resolveMaterial = resolving ? rawMaterial(fullscreen, resolve, {
      u_gathered: { value: gathered.texture }, u_position: { value: gbufferTarget.textures[0] },
      u_normal: { value: gbufferTarget.textures[1] }, u_interleave: { value: settings.screen.interleave },
      u_mm_per_world: { value: 1 }, u_resolve_mm: { value: screen.uniformRadiusMm },
    }, { depthTest: false, depthWrite: false }) : null;
    const proxy = new THREE.Mesh(geometry, shadowMaterial);
    proxy.frustumCulled = false;
    const proxyScene = new THREE.Scene().add(proxy);
    const quad = fullscreenMesh(gatherMaterial);
    const quadScene = new THREE.Scene().add(quad);
    const quadCamera = new THREE.OrthographicCamera();
    let sphere = null;
    let sphereAt = null;
    return {
      scattered,
      targets: [shadowTarget, gbufferTarget, scattered, ...(resolving ? [gathered] : [])],
      pixelTargets: [gbufferTarget, scattered, ...(resolving ? [gathered] : [])],
      materials: [shadowMaterial, gbufferMaterial, gatherMaterial, ...(resolving ? [resolveMaterial] : [])],
      textures: [sampleTexture, rdTexture],
      /** Passes 1-4 of screen/runtime.py for this frame's camera (view-projection, eye). */
      run(viewProjection, eye) {
        const model = mesh.matrixWorld;
        const normalMatrix = new THREE.Matrix3().getNormalMatrix(model);
        if (!sphereAt || !sphereAt.equals(model)) {
          // the box of every transformed vertex, as the moderngl runtime takes it: redone only when the mesh moves
          sphere = worldSphere(mesh);
          sphereAt = model.clone();
        }
        const shadow = lightCamera(sphere, light.direction);
        const det = Math.abs(new THREE.Matrix3().setFromMatrix4(model).determinant());
        const mmPerWorld = scaleMm / Math.cbrt(det);
        for (const m of [shadowMaterial, gbufferMaterial]) {
          m.uniforms.u_model.value.copy(model);
          m.uniforms.u_normal_matrix.value.copy(normalMatrix);
        }
        shadowMaterial.uniforms.u_view_projection.value.copy(shadow.viewProjection);
        const g = gbufferMaterial.uniforms;
        g.u_view_projection.value.copy(viewProjection);
        g.u_light.value.copy(light.direction);
        g.u_intensity.value = light.intensity;
        g.u_light_view_projection.value.copy(shadow.viewProjection);
        g.u_shadow_offset.value = SHADOW_OFFSET_TEXELS * shadow.extent / settings.shadowSize;
        const u = gatherMaterial.uniforms;
        u.u_view_projection.value.copy(viewProjection);
        u.u_eye.value.copy(eye);
        u.u_mm_per_world.value = mmPerWorld;
        if (resolveMaterial) resolveMaterial.uniforms.u_mm_per_world.value = mmPerWorld;
        proxy.material = shadowMaterial;
        draw(proxyScene, shadowTarget, quadCamera, true);
        proxy.material = gbufferMaterial;
        draw(proxyScene, gbufferTarget, quadCamera);
        quad.material = gatherMaterial;
        draw(quadScene, gathered, quadCamera);
        if (resolveMaterial) {
          quad.material = resolveMaterial;
          draw(quadScene, scattered, quadCamera);
        }
      },
    };
  }

  /** Renders `what` into `target` after clearing it to zero (colour, depth 1); `depthOnly`: into
   * its depth alone (three's targets always have a colour buffer, and WebGL refuses a draw into one
   * from depth_only.frag, which has no output; three's cached draw buffers of that framebuffer stay
   * [COLOR0], so it never sets them back). */
  function draw(what, target, camera, depthOnly = false) {
    renderer.setRenderTarget(target);
    if (depthOnly) renderer.getContext().drawBuffers([renderer.getContext().NONE]);
    renderer.setClearColor(0x000000, 0);
    renderer.clear(true, true, true);
    renderer.render(what, camera);
  }

  const size = renderer.getDrawingBufferSize(new THREE.Vector2());
  const linear = floatTarget(size.x, size.y);
  const display = rawMaterial(fullscreen, DISPLAY_FRAGMENT, {
    u_image: { value: linear.texture }, u_scale: { value: new THREE.Vector3(1, 1, 1) }, u_srgb: { value: 1 },
  }, { depthTest: false, depthWrite: false });
  const displayScene = new THREE.Scene().add(fullscreenMesh(display));
  const displayCamera = new THREE.OrthographicCamera();

  const runtime = {
    techniques: MODES.filter((m) => techniques.has(m)),
    mode: techniques.size ? MODES.find((m) => techniques.has(m)) : 'fallback',
    /** Draw with technique `name` ('prt', 'spectral', 'screen'), 'fallback' (the file's own
     * materials) or 'plain' (Lambert, no scattering); meshes without that technique draw plain. */
    setMode(name) {
      if (!MODES.includes(name)) throw new Error(`sssbake: mode must be one of ${MODES.join(', ')}, got ${name}`);
      if (!['fallback', 'plain'].includes(name) && !techniques.has(name)) {
        throw new Error(`sssbake: this file holds no ${name} data (it has: ${[...techniques].join(', ') || 'none'})`);
      }
      this.mode = name;
    },
    /** A directional light: direction towards it (world), colour, intensity (irradiance). */
    setLight({ direction, color, intensity } = {}) {
      if (direction) {
        if (!(direction.lengthSq() > 0)) throw new Error('sssbake: the light direction must not be zero');
        light.direction.copy(direction).normalize();
      }
      if (color !== undefined) light.color.set(color);
      if (intensity !== undefined) light.intensity = intensity;
    },
    /** Draws the current mode into the linear float target (returned), the surface only. */
    renderLinear(camera) {
      const now = renderer.getDrawingBufferSize(new THREE.Vector2());
      if (now.x !== linear.width || now.y !== linear.height) {
        // the per-pixel passes read their targets at gl_FragCoord: they follow the canvas
        for (const target of [linear, ...items.flatMap((item) => (item.screen ? item.screen.pixelTargets : []))]) {
          target.setSize(now.x, now.y);
        }
      }
      scene.updateMatrixWorld(true);
      camera.updateMatrixWorld();
      const viewProjection = new THREE.Matrix4().multiplyMatrices(camera.projectionMatrix, camera.matrixWorldInverse);
      const eye = new THREE.Vector3().setFromMatrixPosition(camera.matrixWorld);
      const fallback = this.mode === 'fallback';
      sun.visible = fallback;
      sun.position.copy(light.direction);
      sun.target.position.set(0, 0, 0);
      sun.color.copy(light.color);
      sun.intensity = light.intensity;
      const saved = { clear: renderer.getClearColor(new THREE.Color()), alpha: renderer.getClearAlpha(), autoClear: renderer.autoClear };
      renderer.autoClear = false;
      try {
        for (const item of items) {
          const { mesh } = item;
          if (fallback) {
            mesh.material = item.original;
            continue;
          }
          const key = item.materials[this.mode] ? this.mode : 'plain';
          if (key === 'screen') item.screen.run(viewProjection, eye);
          const material = item.materials[key];
          const u = material.uniforms;
          u.u_model.value.copy(mesh.matrixWorld);
          u.u_view_projection.value.copy(viewProjection);
          u.u_normal_matrix.value.getNormalMatrix(mesh.matrixWorld);
          u.u_world_to_object.value.setFromMatrix4(mesh.matrixWorld).invert();
          u.u_eye.value.copy(eye);
          u.u_light.value.copy(light.direction);
          u.u_intensity.value = light.intensity;
          mesh.material = material;
          item.savedGeometry = mesh.geometry;
          mesh.geometry = item.geometries[key];
        }
        draw(scene, linear, camera);
      } finally {
        for (const item of items) {
          if (item.savedGeometry) item.mesh.geometry = item.savedGeometry;
          item.savedGeometry = undefined;
          item.mesh.material = item.original;
        }
        renderer.setClearColor(saved.clear, saved.alpha);
        renderer.autoClear = saved.autoClear;
        renderer.setRenderTarget(null);
      }
      return linear;
    },
    /** Draws the current mode to the canvas (or `target`): linear radiance times exposure (and the
     * light's colour in the sssbake modes), sRGB-encoded unless options.srgb is false. */
    render(camera, target = null) {
      this.renderLinear(camera);
      const scale = this.mode === 'fallback' ? new THREE.Color(1, 1, 1) : light.color;
      display.uniforms.u_scale.value.set(scale.r, scale.g, scale.b).multiplyScalar(settings.exposure);
      display.uniforms.u_srgb.value = settings.srgb ? 1 : 0;
      renderer.setRenderTarget(target);
      renderer.render(displayScene, displayCamera);
      renderer.setRenderTarget(null);
    },
    /** The last linear image: Float32Array (height x width x 4), row 0 at the bottom. */
    readLinear() {
      const out = new Float32Array(linear.width * linear.height * 4);
      renderer.readRenderTargetPixels(linear, 0, 0, linear.width, linear.height, out);
      return out;
    },
    dispose() {
      scene.remove(sun, sun.target);
      for (const item of items) {
        for (const m of Object.values(item.materials)) {
          for (const u of Object.values(m.uniforms)) if (u.value && u.value.isTexture && !shared.has(u.value)) u.value.dispose();
          m.dispose();
        }
        for (const g of new Set(Object.values(item.geometries))) g.dispose();
        if (item.screen) {
          item.screen.targets.forEach((t) => t.dispose());
          item.screen.materials.forEach((m) => m.dispose());
          item.screen.textures.forEach((t) => t.dispose());
        }
      }
      linear.dispose();
      display.dispose();
    },
  };
  return runtime;
}
