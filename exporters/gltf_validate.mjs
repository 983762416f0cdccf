// Validates glTF/GLB files with the Khronos glTF-Validator (npm package `gltf-validator`).
// Usage: node gltf_validate.mjs NODE_MODULES_DIR FILE...
// Prints one JSON array: per file, the validator's report or {"error": message}.
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";

const [modulesDir, ...files] = process.argv.slice(2);
// Resolve the package from the given node_modules folder, not from this script's location.
const require = createRequire(path.join(path.resolve(modulesDir), "_sssbake_resolve.js"));
const validator = require("gltf-validator");

const results = [];
for (const file of files) {
  try {
    const data = new Uint8Array(await readFile(file));
    const externalResourceFunction = async (uri) =>
      new Uint8Array(await readFile(path.resolve(path.dirname(file), decodeURIComponent(uri))));
    const report = await validator.validateBytes(data, {
      uri: file,
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
