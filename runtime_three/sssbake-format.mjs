// What the JavaScript readers of SSSBAKE_subsurface (exporters/schema/SSSBAKE_subsurface.md) share:
// runtime_three's GLTFLoader plugin and js/gltf-transform's extension. The Python side is
// exporters/gltf.py (ENCODINGS, table_crc32) and exporters/gltf_tables.py (likely_tool).

export const EXTENSION = 'SSSBAKE_subsurface';

/** glTF componentType and normalized flag of each attribute encoding (exporters/gltf.py ENCODINGS). */
export const ENCODINGS = {
  float32: [5126, false], snorm8: [5120, true], snorm16: [5122, true], unorm8: [5121, true],
  unorm16: [5123, true], uint8: [5121, false], uint16: [5123, false],
};

const CRC_TABLE = (() => {
  const table = new Uint32Array(256);
  for (let n = 0; n < 256; n++) {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    table[n] = c >>> 0;
  }
  return table;
})();

/** zlib CRC-32 of `bytes` (Uint8Array) as 8 lowercase hex digits: a table reference's `crc32`. */
export function crc32Hex(bytes) {
  let c = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) c = CRC_TABLE[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return ((c ^ 0xffffffff) >>> 0).toString(16).padStart(8, '0');
}

/** The tool that likely broke a file's sssbake data, from its `asset.generator`. */
export function likelyTool(generator) {
  const g = String(generator || '');
  if (g.includes('glTF-Transform')) return 'glTF-Transform';
  if (g.includes('gltfpack')) return 'gltfpack';
  if (g.includes('Khronos glTF Blender I/O')) return 'Blender (Khronos glTF Blender I/O)';
  return `a tool that did not keep the ${EXTENSION} extension`;
}
