// Runs the Khronos glTF validator (npm package gltf-validator) on one file and prints its JSON report.
// usage: node validate_gltf.cjs DIR_WITH_NODE_MODULES FILE.glb
const fs = require("fs");
const validator = require(require.resolve("gltf-validator", { paths: [process.argv[2]] }));
const bytes = new Uint8Array(fs.readFileSync(process.argv[3]));
validator
  .validateBytes(bytes, { maxIssues: 200 })
  .then((report) => console.log(JSON.stringify(report)))
  .catch((error) => {
    console.error(String(error));
    process.exit(1);
  });
