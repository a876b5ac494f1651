// Builds the viewer into one folder (default ../build/web, or argv[2]): the
// page, its bundled module, the component's module (surfcast.js) and its
// three.js layer (surfcast-three.js), the example apps, three.js, the decode
// worker and draco3d's WASM decoder.
// Nothing is fetched at run time from anywhere but the folder itself.
import { build } from "esbuild";
import { programs, shaderDir, sharedConstants } from "./glsl_es.mjs";
import { copyFileSync, mkdirSync } from "node:fs";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const out = resolve(process.argv[2] ?? join(here, "..", "build", "web"));
mkdirSync(out, { recursive: true });
// "surfcast:shaders": the programs glsl_es.mjs generates from client/shaders.
const shaders = {
  name: "surfcast-shaders",
  setup(b) {
    b.onResolve({ filter: /^surfcast:shaders$/ }, (args) => ({ path: args.path, namespace: "surfcast" }));
    b.onLoad({ filter: /.*/, namespace: "surfcast" }, () => ({
      contents: `export const programs = ${JSON.stringify(programs())};\nexport const constants = ${JSON.stringify(sharedConstants())};\n`,
      loader: "js", watchDirs: [shaderDir] }));
  },
};
const common = { bundle: true, minify: true, sourcemap: true, target: ["es2020"], logLevel: "warning", plugins: [shaders] };
await build({ ...common, entryPoints: [join(here, "src/main.ts")], outfile: join(out, "viewer.js"), format: "esm" });
// The component alone, for apps that embed it (docs/WEB.md, "The component"),
// and its three.js layer, which imports "three" from the app (an import map).
await build({ ...common, entryPoints: [join(here, "src/viewer.ts")], outfile: join(out, "surfcast.js"), format: "esm" });
await build({ ...common, entryPoints: [join(here, "src/three_layer.ts")], outfile: join(out, "surfcast-three.js"), format: "esm",
              external: ["three"] });
await build({ ...common, entryPoints: [join(here, "src/decode_worker.ts")], outfile: join(out, "decode_worker.js"), format: "iife" });
for (const f of ["index.html", "style.css"]) copyFileSync(join(here, f), join(out, f));
// The example apps, flat beside the page (surfcast-serve serves one level),
// and three.js for the three.js one (npm's copy, pinned by the lockfile).
for (const f of ["embed.html", "three.html"]) copyFileSync(join(here, "examples", f), join(out, f));
for (const f of ["three.module.js", "three.core.js"]) copyFileSync(join(here, "node_modules", "three", "build", f), join(out, f));
copyFileSync(join(here, "node_modules", "three", "examples", "jsm", "controls", "OrbitControls.js"), join(out, "OrbitControls.js"));
const draco = join(here, "node_modules", "draco3d");
copyFileSync(join(draco, "draco_decoder_nodejs.js"), join(out, "draco_decoder.js"));
copyFileSync(join(draco, "draco_decoder.wasm"), join(out, "draco_decoder.wasm"));
console.log(`web viewer built into ${out}`);
