// Khronos glTF-Validator over glb files: `node tests/js/validate_glb.mjs <file-or-dir>...`
// Prints one JSON object {files, errors, warnings, infos, hints, reports:[{file, numErrors, messages}]} and
// exits 1 when any file has an error. The validator is a library (npm gltf-validator has no CLI).
import fs from 'node:fs';
import path from 'node:path';
import validator from 'gltf-validator';

function* glbs(p) {
  const st = fs.statSync(p);
  if (st.isDirectory()) {
    for (const e of fs.readdirSync(p).sort()) yield* glbs(path.join(p, e));
  } else if (p.endsWith('.glb')) {
    yield p;
  }
}

const summary = { files: 0, errors: 0, warnings: 0, infos: 0, hints: 0, reports: [] };
for (const arg of process.argv.slice(2)) {
  for (const f of glbs(arg)) {
    const r = await validator.validateBytes(new Uint8Array(fs.readFileSync(f)), {
      uri: path.basename(f),
      maxIssues: 100,
      externalResourceFunction: (u) =>
        Promise.resolve(new Uint8Array(fs.readFileSync(path.join(path.dirname(f), decodeURIComponent(u))))),
    });
    const i = r.issues;
    summary.files += 1;
    summary.errors += i.numErrors;
    summary.warnings += i.numWarnings;
    summary.infos += i.numInfos;
    summary.hints += i.numHints;
    if (i.numErrors || i.numWarnings) {
      summary.reports.push({ file: f, numErrors: i.numErrors, numWarnings: i.numWarnings,
        messages: i.messages.filter((m) => m.severity <= 1).slice(0, 20) });
    }
  }
}
console.log(JSON.stringify(summary, null, 1));
process.exit(summary.errors ? 1 : 0);
