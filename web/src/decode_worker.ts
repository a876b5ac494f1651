// The decode worker: loads the draco3d WASM decoder once, then turns blocks
// into GPU surfels (block_decode.ts) as the streamer posts them.

import { decodeBlock, type DecodeJob, type DracoModule } from "./block_decode.js";

declare const self: DedicatedWorkerGlobalScope;
declare function importScripts(...urls: string[]): void;
declare const DracoDecoderModule: (options: { wasmBinary: ArrayBuffer }) => Promise<DracoModule>;

let ready: Promise<DracoModule> | null = null;

function load(): Promise<DracoModule> {
  ready ??= (async () => {
    importScripts("draco_decoder.js");
    const response = await fetch("draco_decoder.wasm");
    if (!response.ok) throw new Error(`draco_decoder.wasm: HTTP ${response.status}`);
    return DracoDecoderModule({ wasmBinary: await response.arrayBuffer() });
  })();
  return ready;
}

self.onmessage = async (event: MessageEvent<DecodeJob>) => {
  const job = event.data;
  try {
    const draco = await load();
    const result = decodeBlock(draco, job);
    self.postMessage(result, result.surfels ? [result.surfels] : []);
  } catch (e) {
    self.postMessage({ id: job.id, error: `the Draco decoder did not load: ${(e as Error).message}` });
  }
};
