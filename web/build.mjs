// Builds the viewer into one folder (default ../build/web, or argv[2]): the
// page, its bundled module, the component's module (surfcast.js) and its
// three.js layer (surfcast-three.js), the example apps, three.js, the decode
// worker and draco3d's WASM decoder.
// Nothing is fetched at run time from anywhere but the folder itself.
// Then the npm package "surfcast" into its own folder (default
// ../build/web-package, or argv[3]), ready for `npm pack` (docs/WEB.md,
// "The npm package").
import { build } from "esbuild";
import { programs, shaderDir, sharedConstants } from "./glsl_es.mjs";
import { execFileSync } from "node:child_process";
import { copyFileSync, mkdirSync, readdirSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const out = resolve(process.argv[2] ?? join(here, "..", "build", "web"));
const pkg = resolve(process.argv[3] ?? join(dirname(out), "web-package"));
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

// The npm package: the component and its three.js layer as ES modules that
// share one chunk (one SurfcastViewer class for both entry points), three
// left to the app (a peer dependency), not minified (the app's bundler
// minifies); beside them the decode worker and draco3d's decoder, which
// viewer.ts finds beside itself; and tsc's declarations of both entry points.
const dist = join(pkg, "dist");
rmSync(pkg, { recursive: true, force: true });
mkdirSync(dist, { recursive: true });
await build({ ...common, minify: false, entryPoints: { surfcast: join(here, "src/viewer.ts"), "surfcast-three": join(here, "src/three_layer.ts") },
              outdir: dist, format: "esm", splitting: true, external: ["three"] });
for (const f of ["decode_worker.js", "decode_worker.js.map", "draco_decoder.js", "draco_decoder.wasm"]) copyFileSync(join(out, f), join(dist, f));
execFileSync(process.execPath, [join(here, "node_modules", "typescript", "bin", "tsc"), "-p", join(here, "tsconfig.package.json"),
                                "--declarationDir", join(dist, "types")], { stdio: "inherit" });
copyFileSync(join(here, "README.md"), join(pkg, "README.md"));
copyFileSync(join(here, "..", "LICENSE"), join(pkg, "LICENSE"));
const web = JSON.parse(readFileSync(join(here, "package.json"), "utf8"));
const three = web.dependencies.three, threeTypes = web.dependencies["@types/three"];
const manifest = {
  name: "surfcast",
  version: web.version,
  description: "Streams Surfcast tile sets into a canvas or a three.js scene and draws them with EWA surface splatting on WebGL2",
  license: "Apache-2.0",
  keywords: ["point cloud", "splatting", "ewa", "lidar", "webgl2", "three", "level of detail", "streaming"],
  type: "module",
  exports: {
    ".": { types: "./dist/types/viewer.d.ts", default: "./dist/surfcast.js" },
    "./three": { types: "./dist/types/three_layer.d.ts", default: "./dist/surfcast-three.js" },
    // The files the component loads beside itself, for apps that copy them
    // where their bundle is served (require.resolve("surfcast/decode_worker.js")).
    "./decode_worker.js": "./dist/decode_worker.js",
    "./draco_decoder.js": "./dist/draco_decoder.js",
    "./draco_decoder.wasm": "./dist/draco_decoder.wasm",
    "./package.json": "./package.json",
  },
  types: "./dist/types/viewer.d.ts",
  // What ships, every file by name (npm adds package.json, README.md and LICENSE).
  files: readdirSync(dist, { recursive: true, withFileTypes: true }).filter((e) => e.isFile())
    .map((e) => join(e.parentPath ?? e.path, e.name).slice(pkg.length + 1)).sort(),
  // Only surfcast/three needs three (and TypeScript apps its types): the
  // app's own copy, never a second one, of the release the layer is built
  // and tested with (three changes its API between 0.x releases: ^0.x.y
  // takes patch releases only).
  peerDependencies: { three: `^${three}`, "@types/three": `^${threeTypes}` },
  peerDependenciesMeta: { three: { optional: true }, "@types/three": { optional: true } },
};
writeFileSync(join(pkg, "package.json"), JSON.stringify(manifest, null, 2) + "\n");
console.log(`npm package ${manifest.name}@${manifest.version} built into ${pkg}`);
