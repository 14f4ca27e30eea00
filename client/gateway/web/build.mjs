// Bundles the viewer page into one folder that fslam-gateway serves (no CDN, nothing fetched at
// run time): node build.mjs [OUT_DIR], default ../../../build/viewer.
import { build } from "esbuild";
import { copyFileSync, mkdirSync, rmSync } from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const out = path.resolve(process.argv[2] || path.join(here, "..", "..", "..", "build", "viewer"));
rmSync(out, { recursive: true, force: true });
mkdirSync(out, { recursive: true });
await build({
  entryPoints: [path.join(here, "src", "main.js")],
  bundle: true,
  format: "esm",
  minify: true,
  target: "es2020",
  outfile: path.join(out, "viewer.js"),
  logLevel: "warning",
});
for (const f of ["index.html", "viewer.css"]) copyFileSync(path.join(here, "src", f), path.join(out, f));
console.log(`viewer bundled into ${out}`);
