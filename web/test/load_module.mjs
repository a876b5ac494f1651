// Loads one of the viewer's TypeScript modules under node, without a browser:
// esbuild (the build's bundler) turns it into JavaScript in a temporary
// folder, which is imported and removed.

import { mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join } from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";
import { build } from "esbuild";

export const web = join(dirname(fileURLToPath(import.meta.url)), "..");
// The cases both clients run (the C++ tests read them too).
export const conformance = join(web, "..", "tests", "conformance");

// `source`: the module's exports, as TypeScript (e.g. 'export * from "./src/format.ts";'),
// or a path under web/ ("src/format.ts") whose exports are all taken.
export async function loadModule(source) {
  const contents = source.endsWith(".ts") ? `export * from "./${source}";` : source;
  const out = mkdtempSync(join(tmpdir(), "surfcast-module-"));
  try {
    const file = join(out, "module.mjs");
    await build({ stdin: { contents, resolveDir: web, loader: "ts" }, bundle: true, format: "esm", platform: "node",
                  outfile: file, logLevel: "warning" });
    return await import(pathToFileURL(file).href);
  } finally {
    rmSync(out, { recursive: true, force: true });
  }
}
