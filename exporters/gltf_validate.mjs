// Validates glTF/GLB files with the Khronos glTF-Validator (npm package `gltf-validator`).
// Usage: node gltf_validate.mjs NODE_MODULES_DIR HEX...
// Each HEX is a file's path, its bytes in hex: a POSIX name need not be UTF-8, and node's strings
// (its arguments too) are; as a Buffer, a path reaches the file whatever its bytes.
// Prints one JSON array: per file, the validator's report or {"error": message}.
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";

const [modulesDir, ...hexes] = process.argv.slice(2);
// Resolve the package from the given node_modules folder, not from this script's location.
const require = createRequire(path.join(path.resolve(modulesDir), "_sssbake_resolve.js"));
const validator = require("gltf-validator");

const results = [];
for (const hex of hexes) {
  // latin1 maps each byte to one character and back, so path.resolve works on the bytes themselves
  const file = Buffer.from(hex, "hex").toString("latin1");
  const bytes = (name) => Buffer.from(name, "latin1");
  try {
    const data = new Uint8Array(await readFile(bytes(file)));
    const externalResourceFunction = async (uri) => {
      const name = Buffer.from(decodeURIComponent(uri), "utf8").toString("latin1");
      return new Uint8Array(await readFile(bytes(path.resolve(path.dirname(file), name))));
    };
    const report = await validator.validateBytes(data, {
      uri: bytes(file).toString("utf8"),
      maxIssues: 0,
      writeTimestamp: false,
      externalResourceFunction,
    });
    results.push(report);
  } catch (error) {
    results.push({ error: String(error) });
  }
}
process.stdout.write(JSON.stringify(results));
