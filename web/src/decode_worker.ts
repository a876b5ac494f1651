// The decode worker: loads the draco3d WASM decoder once, then turns blocks
// into GPU surfels (block_decode.ts) as the streamer posts them. The
// decoder's files are where the first message says (the streamer resolves
// them beside its module), else beside this worker.

import { decodeBlock, type DecodeJob, type DecoderUrls, type DracoModule } from "./block_decode.js";

declare const self: DedicatedWorkerGlobalScope;
declare function importScripts(...urls: string[]): void;
declare const DracoDecoderModule: (options: { wasmBinary: ArrayBuffer }) => Promise<DracoModule>;

let ready: Promise<DracoModule> | null = null;
let urls: DecoderUrls = { draco: "draco_decoder.js", wasm: "draco_decoder.wasm" };

function load(): Promise<DracoModule> {
  ready ??= (async () => {
    importScripts(urls.draco);
    const response = await fetch(urls.wasm);
    if (!response.ok) throw new Error(`${urls.wasm}: HTTP ${response.status}`);
    return DracoDecoderModule({ wasmBinary: await response.arrayBuffer() });
  })();
  return ready;
}

self.onmessage = async (event: MessageEvent<DecodeJob | { decoder: DecoderUrls }>) => {
  if ("decoder" in event.data) {
    urls = event.data.decoder;
    return;
  }
  const job = event.data;
  try {
    const draco = await load();
    const result = decodeBlock(draco, job);
    self.postMessage(result, result.surfels ? [result.surfels] : []);
  } catch (e) {
    self.postMessage({ id: job.id, error: `the Draco decoder did not load: ${(e as Error).message}` });
  }
};
