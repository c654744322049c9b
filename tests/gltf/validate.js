// Runs the Khronos glTF validator (npm package gltf-validator) on one .glb/.gltf file.
// Usage: node tests/gltf/validate.js FILE   — prints the issue counts and every error and
// warning; exits 1 if the validator reports any error (or cannot read the file).
const fs = require("fs");
const validator = require("gltf-validator");

const file = process.argv[2];
if (!file) {
  console.error("usage: node validate.js FILE.glb");
  process.exit(2);
}
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 100 })
  .then((report) => {
    const i = report.issues;
    console.log(
      `gltf-validator ${report.validatorVersion}: ${i.numErrors} errors, ${i.numWarnings} warnings, ` +
        `${i.numInfos} infos, ${i.numHints} hints`
    );
    for (const m of i.messages) {
      if (m.severity <= 1) {
        console.log(`  ${m.severity === 0 ? "error" : "warning"} ${m.code} at ${m.pointer || m.offset}: ${m.message}`);
      }
    }
    process.exit(i.numErrors > 0 ? 1 : 0);
  })
  .catch((e) => {
    console.error(`the validator could not read ${file}: ${e}`);
    process.exit(1);
  });
