// Runs the Khronos glTF validator (npm package `gltf-validator`, found through NODE_PATH) on one
// file and prints its JSON report; exit code 0 when the report has no errors, 1 otherwise.
// Usage: NODE_PATH=DIR/node_modules node gltf_validate.js FILE.glb
// Used by the ignored test `gltf_validator_accepts_scene_glb` in tests/delight.rs.
const fs = require('fs');
const validator = require('gltf-validator');
const file = process.argv[2];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { uri: file, maxIssues: 100 })
  .then((report) => {
    console.log(JSON.stringify(report, null, 2));
    process.exit(report.issues.numErrors === 0 ? 0 : 1);
  })
  .catch((error) => {
    console.error('validation failed:', error);
    process.exit(2);
  });
