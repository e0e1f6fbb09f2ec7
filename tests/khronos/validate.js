// Validate glTF files with the Khronos glTF validator; print one JSON report per file, one per line:
// {"file", "errors", "warnings", "infos", "messages": [[severity, code, pointer, message], ...]}.
// Usage: node validate.js FILE [FILE ...]   (exit 2 when a file cannot be read or validated)
const fs = require("fs");
const validator = require("gltf-validator");

async function main(files) {
  for (const file of files) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 100 });
    const issues = report.issues;
    console.log(JSON.stringify({
      file,
      errors: issues.numErrors,
      warnings: issues.numWarnings,
      infos: issues.numInfos,
      messages: issues.messages.map((m) => [m.severity, m.code, m.pointer || "", m.message]),
    }));
  }
}

main(process.argv.slice(2)).catch((e) => {
  console.error(String(e));
  process.exit(2);
});
