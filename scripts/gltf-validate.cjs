// Validates a glTF file with the Khronos glTF validator (the npm package
// gltf-validator, installed under .tools by scripts/install-deps.sh) and
// prints its report as JSON; exits 1 if the report has errors.
const fs = require('fs');
const path = require('path');
const validator = require(path.join(__dirname, '..', '.tools', 'node_modules', 'gltf-validator'));

const file = process.argv[2];
if (!file) {
  console.error('usage: node scripts/gltf-validate.cjs FILE.glb');
  process.exit(2);
}
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { uri: path.basename(file), maxIssues: 200 })
  .then((report) => {
    console.log(JSON.stringify(report, null, 1));
    process.exit(report.issues.numErrors > 0 ? 1 : 0);
  })
  .catch((e) => {
    console.error(`${file}: ${e}`);
    process.exit(2);
  });
