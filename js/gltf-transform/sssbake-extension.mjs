// glTF-Transform 4.x extension for SSSBAKE_subsurface (exporters/schema/SSSBAKE_subsurface.md).
//
// Without it glTF-Transform drops the extension (an unknown optional extension) and prunes the tables
// it references; with it every table reference becomes a graph edge to its Accessor, so prune keeps
// the tables and the indices that weld/dedup/reorder renumber are rewritten on write. Each table's
// name, count, type, componentType and CRC-32 are checked on read and again on write, and every mesh's
// primitives, positions and `_` attributes on write: a transform that changed what the data belongs
// to (join, quantize, ...) makes the write fail with one line instead of writing data that no longer fits.
import { Extension, ExtensionProperty, PropertyType, RefMap } from '@gltf-transform/core';

import { crc32Hex, ENCODINGS, EXTENSION as SSSBAKE_SUBSURFACE, likelyTool } from '../../runtime_three/sssbake-format.mjs';

export { SSSBAKE_SUBSURFACE };
const SCHEMA_MAJOR = '2';

const COMPRESSIONS = ['KHR_draco_mesh_compression', 'EXT_meshopt_compression'];

// A table reference is known by its `name` and `crc32` (its `accessor` index is only a hint).
function isTableRef(value) {
  return value !== null && typeof value === 'object' && !Array.isArray(value)
    && typeof value.name === 'string' && typeof value.crc32 === 'string';
}

/** Every table reference in an extension object: [JSON pointer, reference object], depth first. */
function listTableRefs(value, pointer = '') {
  if (isTableRef(value)) return [[pointer, value]];
  if (value === null || typeof value !== 'object') return [];
  const entries = Array.isArray(value) ? value.map((v, i) => [String(i), v]) : Object.entries(value);
  return entries.flatMap(([key, v]) => listTableRefs(v, `${pointer}/${key.replace(/~/g, '~0').replace(/\//g, '~1')}`));
}

/** Why an accessor (`name`, `count`, `type`, `componentType`, typed `array` or null) does not hold a
 * table reference's data, or null when it does; no CRC-32 check without an array. */
function tableMismatch({ name, count, type, componentType, array }, ref) {
  if (name !== ref.name) return `accessor is named "${name}"`;
  if (count !== ref.count) return `count ${count}, expected ${ref.count}`;
  if (type !== ref.type) return `type ${type}, expected ${ref.type}`;
  if (componentType !== ref.componentType) return `componentType ${componentType}, expected ${ref.componentType}`;
  if (!array) return null;
  // glTF-Transform keeps elements as a dense typed array (sparse substitutions applied), little-endian
  // on every platform it runs on: the bytes the schema's CRC-32 is defined over.
  const crc = crc32Hex(new Uint8Array(array.buffer, array.byteOffset, array.byteLength));
  return crc === ref.crc32 ? null : `crc32 ${crc}, expected ${ref.crc32}`;
}

/**
 * One SSSBAKE_subsurface object (on the Root, a Mesh or a Material): its JSON with each table
 * reference's `accessor` index replaced by an edge in the `tables` RefMap, keyed by the reference's
 * JSON pointer inside the object (e.g. `/prt/directions`).
 */
export class SSSBakeData extends ExtensionProperty {
  static EXTENSION_NAME = SSSBAKE_SUBSURFACE;

  init() {
    this.extensionName = SSSBAKE_SUBSURFACE;
    this.propertyType = 'SSSBakeData';
    this.parentTypes = [PropertyType.ROOT, PropertyType.MESH, PropertyType.MATERIAL];
  }

  getDefaults() {
    return Object.assign(super.getDefaults(), { data: {}, tables: new RefMap() });
  }

  /** The extension object, table references without their `accessor` index. */
  getData() {
    return this.get('data');
  }

  setData(data) {
    return this.set('data', data);
  }

  getTable(pointer) {
    return this.getRefMap('tables', pointer);
  }

  setTable(pointer, accessor) {
    return this.setRefMap('tables', pointer, accessor, { usage: 'OTHER' });
  }

  listTablePointers() {
    return this.listRefMapKeys('tables');
  }
}

/** glTF-Transform Extension for SSSBAKE_subsurface; register it next to ALL_EXTENSIONS. */
export class SSSBakeSubsurface extends Extension {
  static EXTENSION_NAME = SSSBAKE_SUBSURFACE;
  extensionName = SSSBAKE_SUBSURFACE;

  createData() {
    return new SSSBakeData(this.document.getGraph());
  }

  read(context) {
    const json = context.jsonDoc.json;
    const tool = likelyTool(json.asset && json.asset.generator);
    const rootDef = (json.extensions || {})[SSSBAKE_SUBSURFACE];
    const major = String((rootDef || {}).schemaVersion || '').split('.')[0];
    if (major !== SCHEMA_MAJOR) {
      throw new Error(`${SSSBAKE_SUBSURFACE}: root schemaVersion "${(rootDef || {}).schemaVersion}" is not `
        + `${SCHEMA_MAJOR}.x; this extension reads schema ${SCHEMA_MAJOR}.x`);
    }
    const attach = (def, target) => {
      if (!def || !def.extensions || !def.extensions[SSSBAKE_SUBSURFACE]) return;
      const data = structuredClone(def.extensions[SSSBAKE_SUBSURFACE]);
      const property = this.createData();
      for (const [pointer, ref] of listTableRefs(data)) {
        property.setTable(pointer, this._resolve(context, ref, tool));
        delete ref.accessor;
      }
      target.setExtension(SSSBAKE_SUBSURFACE, property.setData(data));
    };
    attach(json, this.document.getRoot());
    (json.meshes || []).forEach((def, i) => attach(def, context.meshes[i]));
    (json.materials || []).forEach((def, i) => attach(def, context.materials[i]));
    return this;
  }

  /** The schema's resolution rule on the file's accessor definitions: the indexed one if its name
   * matches, else the unique one of that name; then count, type and componentType must match, and
   * the CRC-32 where the data is already decoded (sparse and zero-filled accessors are filled after
   * extensions read; `write` checks every table's CRC-32). */
  _resolve(context, ref, tool) {
    const defs = context.jsonDoc.json.accessors || [];
    let index = ref.accessor;
    if (!defs[index] || defs[index].name !== ref.name) {
      const named = defs.flatMap((def, i) => (def.name === ref.name ? [i] : []));
      index = named.length === 1 ? named[0] : -1;
    }
    const def = defs[index];
    const dense = def && def.bufferView !== undefined && !def.sparse;
    const why = def ? tableMismatch({ ...def, array: dense ? context.accessors[index].getArray() : null }, ref)
      : 'no accessor of that name';
    if (why) {
      throw new Error(`${SSSBAKE_SUBSURFACE}: table ${ref.name} is stale (${why}); the file was likely rewritten `
        + `by ${tool}: rebake it with sssbake`);
    }
    return context.accessors[index];
  }

  write(context) {
    const json = context.jsonDoc.json;
    const root = this.document.getRoot();
    const put = (property, def) => {
      const data = structuredClone(property.getData());
      for (const [pointer, ref] of listTableRefs(data)) {
        const accessor = property.getTable(pointer);
        const why = accessor ? tableMismatch({
          name: accessor.getName(), count: accessor.getCount(), type: accessor.getType(),
          componentType: accessor.getComponentType(), array: accessor.getArray(),
        }, ref) : 'its accessor was removed';
        if (why) throw new Error(`${SSSBAKE_SUBSURFACE}: a transform changed table ${ref.name} (${why}); not writing it`);
        ref.accessor = context.accessorIndexMap.get(accessor);
      }
      def.extensions = def.extensions || {};
      def.extensions[SSSBAKE_SUBSURFACE] = data;
    };
    // Draco quantizes vertex attributes (lossy) and meshopt comes with quantize; sssbake's readers
    // decode neither, so their output would be unreadable or subtly wrong.
    const compression = root.listExtensionsUsed().map((e) => e.extensionName).filter((n) => COMPRESSIONS.includes(n));
    if (compression.length) {
      throw new Error(`${SSSBAKE_SUBSURFACE}: ${compression.join(', ')} re-encodes the vertices sssbake's data `
        + 'indexes; not writing it (optimize: --compress false)');
    }
    const rootData = root.getExtension(SSSBAKE_SUBSURFACE);
    if (rootData) put(rootData, json);
    const encodings = new Map(((rootData && rootData.getData().attributes) || []).map((a) => [a.name, a.encoding]));
    for (const mesh of root.listMeshes()) {
      const data = mesh.getExtension(SSSBAKE_SUBSURFACE);
      if (!data) continue;
      checkVertices(mesh, data.getData(), encodings);
      put(data, json.meshes[context.meshIndexMap.get(mesh)]);
    }
    for (const material of root.listMaterials()) {
      const data = material.getExtension(SSSBAKE_SUBSURFACE);
      if (data) put(data, json.materials[context.materialIndexMap.get(material)]);
    }
    return this;
  }
}

/** Throw when a transform changed a mesh that carries sssbake data beyond what the data survives: its
 * primitive list (`vertexCounts` has one entry per primitive), the frame of its float positions, or
 * the root-declared encoding of a `_` attribute of the mesh's `attributeTypes`. The vertex count may
 * change (weld, simplify): no table is indexed by render vertex, and per-vertex values move with
 * their vertex. */
function checkVertices(mesh, data, encodings) {
  const prims = mesh.listPrimitives();
  const counts = data.vertexCounts || [];
  const where = `mesh "${mesh.getName()}"`;
  if (prims.length !== counts.length) {
    throw new Error(`${SSSBAKE_SUBSURFACE}: ${where} has ${prims.length} primitives, baked with ${counts.length} `
      + '(join/merge changed it); not writing it');
  }
  const types = data.attributeTypes || {};
  prims.forEach((prim, p) => {
    const position = prim.getAttribute('POSITION');
    const count = position.getCount();
    // Quantized positions come with a rescaled node transform: the mesh's frame, in which scaleMm
    // and the tables' lengths are given, is no longer the baked one.
    if (position.getComponentType() !== 5126) {
      throw new Error(`${SSSBAKE_SUBSURFACE}: ${where} primitive ${p} has quantized positions (quantize/meshopt `
        + 'changed the mesh frame); not writing it');
    }
    for (const [semantic, type] of Object.entries(types)) {
      const accessor = prim.getAttribute(semantic);
      const [componentType, normalized] = ENCODINGS[encodings.get(semantic)] || [];
      const ok = accessor && accessor.getCount() === count && accessor.getType() === type
        && accessor.getComponentType() === componentType && accessor.getNormalized() === normalized;
      if (!ok) {
        throw new Error(`${SSSBAKE_SUBSURFACE}: ${where} primitive ${p} attribute ${semantic} is missing or not `
          + `${encodings.get(semantic)} ${type} (a transform re-encoded or removed it); not writing it`);
      }
    }
  });
}
