// Where a tile set's bytes come from: its folder URL on any host that honours
// Range (nginx, an object store, a CDN, surfcast-serve), with POST
// {set}/batch where tileset.json's answer offers it (surfcast-serve's
// Surfcast-Batch header) without a redirect. Transient faults
// (network errors, responses cut short, 408, 429, 5xx: HttpError.transient)
// are retried with backoff by the caller; everything else, and any error that
// is not an HttpError (a CRC or decoding failure of the set's fixed bytes),
// fails at once, naming the URL or node: the C++ client's classes
// (client/stream/streamer.h), though only it reads tileset.json again to tell
// a rebuilt set from a damaged one. Redirects are the browser's: it keeps
// https pages from http data, and drops Authorization across origins.

import type { Box } from "./lod_selection.js";

export class HttpError extends Error {
  constructor(message: string, readonly transient: boolean) {
    super(message);
  }
}

export interface SourceOptions {
  token?: string; // sent as Authorization: Bearer on every data request
  timeoutMs?: number;
}

export class TileSource {
  readonly base: string; // the set's folder URL, no trailing slash
  // The most node keys one POST {set}/batch may hold: tileset.json's answer
  // offers it (Surfcast-Batch: N, docs/PROTOCOL.md "Batch"); 0 elsewhere,
  // where nodes go by Range only, so a static host never sees a POST.
  batchNodes = 0;
  // The set's version (hierarchy.crc32) batches ask for (?v=): surfcast-serve
  // keeps serving it after an update until the one after (PROTOCOL.md, "Versions").
  version: number | undefined;
  requests = 0;
  bytes = 0;

  constructor(base: string, private options: SourceOptions = {}) {
    this.base = base.replace(/\/+$/, "");
  }

  // surfcast-serve's LAZ export of the points in `box` (world coordinates,
  // bounds included; every point where undefined) of the `classes` given
  // (all where undefined): docs/PROTOCOL.md, "Export". Static hosts have no
  // such route (404).
  async exportLaz(box?: Box, classes?: number[]): Promise<Blob> {
    const query = new URLSearchParams();
    if (box) query.set("bbox", [...box.min, ...box.max].join(","));
    if (classes) query.set("classes", classes.join(","));
    const url = `${this.base}/export.laz${query.size ? `?${query}` : ""}`;
    ++this.requests;
    const r = await fetch(url, { headers: this.headers() });  // no timeout: a large export takes a while
    if (!r.ok) {
      const why = r.status === 404 ? " (this host does not export points: surfcast-serve does)" : "";
      throw new Error(`${url}: HTTP ${r.status}${why}: ${(await r.text()).trim()}`);
    }
    return r.blob();
  }

  private headers(extra: Record<string, string> = {}): Record<string, string> {
    return this.options.token ? { ...extra, Authorization: `Bearer ${this.options.token}` } : extra;
  }

  // tileset.json (or another small file) again unless it is unchanged since
  // the last call: null then. Asked with If-None-Match where the host gave
  // an ETag (a 304 costs a few hundred bytes), else compared whole. A
  // follower polls with it (viewer.ts, ViewerOptions.follow).
  private validator = "";
  private lastText: string | null = null;
  async changedText(name: string, limit: number): Promise<string | null> {
    const url = `${this.base}/${name}`;
    const r = await this.send(url, { headers: this.headers(this.validator ? { "If-None-Match": this.validator } : {}) }, url, true);
    if (r.status === 304) return null;
    const text = new TextDecoder().decode(await this.body(r, limit, url));
    this.validator = r.headers.get("ETag") ?? "";
    if (text === this.lastText) return null;
    this.lastText = text;
    return text;
  }

  // `notModified`: a 304 is an answer too (a conditional request's).
  private async send(url: string, init: RequestInit, what: string, notModified = false): Promise<Response> {
    const controller = new AbortController();
    const timer = setTimeout(() => controller.abort(), this.options.timeoutMs ?? 30000);
    ++this.requests;
    try {
      const r = await fetch(url, { ...init, signal: controller.signal, cache: "no-cache" });
      if (r.ok || (notModified && r.status === 304)) return r;
      const transient = r.status === 408 || r.status === 429 || r.status >= 500;
      const why = r.status === 401 ? " (the host wants a token: add #token=... to the page's URL)" : r.status === 404 ? " (not found)" : "";
      throw new HttpError(`${what}: HTTP ${r.status}${why}`, transient);
    } catch (e) {
      if (e instanceof HttpError) throw e;
      const aborted = (e as Error).name === "AbortError";
      throw new HttpError(`${what}: ${aborted ? "timed out" : `unreachable (${(e as Error).message})`}`, true);
    } finally {
      clearTimeout(timer);
    }
  }

  private async body(r: Response, limit: number, what: string): Promise<Uint8Array> {
    const declared = Number(r.headers.get("Content-Length") ?? "0");
    if (declared > limit) throw new HttpError(`${what}: ${declared} bytes, more than the ${limit} expected`, false);
    let bytes: Uint8Array;
    try {
      bytes = new Uint8Array(await r.arrayBuffer());
    } catch (e) {
      throw new HttpError(`${what}: the response broke off (${(e as Error).message})`, true);
    }
    if (bytes.length > limit) throw new HttpError(`${what}: ${bytes.length} bytes, more than the ${limit} expected`, false);
    this.bytes += bytes.length;
    return bytes;
  }

  // A whole small file; tileset.json's answer also says whether the host batches.
  async text(name: string, limit: number): Promise<string> {
    const url = `${this.base}/${name}`;
    const r = await this.send(url, { headers: this.headers() }, url);
    const bytes = await this.body(r, limit, url);
    if (name === "tileset.json") {
      // Batches go to the set's own URL (the host that redirected would be
      // posted to, and fetch turns a POST redirected by 301-303 into a
      // GET): one offered at a redirect's target is not taken.
      const offered = r.redirected ? "" : r.headers.get("Surfcast-Batch") ?? "";
      this.batchNodes = /^[0-9]+$/.test(offered) && Number(offered) <= 1e6 ? Number(offered) : 0;  // as C++ takes it
    }
    return new TextDecoder().decode(bytes);
  }

  // Bytes [offset, offset + size) of `name`, exactly.
  async range(name: string, offset: number, size: number): Promise<Uint8Array> {
    const url = `${this.base}/${name}`;
    const what = `${url} bytes ${offset}-${offset + size - 1}`;
    const r = await this.send(url, { headers: this.headers({ Range: `bytes=${offset}-${offset + size - 1}` }) }, what);
    if (r.status !== 206)
      throw new HttpError(`${url}: the host ignores Range (HTTP ${r.status} instead of 206); serve the set from one that honours it (nginx, an object store or CDN, surfcast-serve)`, false);
    const bytes = await this.body(r, size, what);
    if (bytes.length !== size) throw new HttpError(`${what}: ${bytes.length} bytes arrived`, true);
    return bytes;
  }

  // Several nodes' blobs in one POST (surfcast-serve's batch): for each key in
  // order, a little-endian u32 length, then the blob.
  async blobs(nodes: { key: string; blockSize: number }[]): Promise<Uint8Array[]> {
    const url = `${this.base}/batch${this.version === undefined ? "" : `?v=${this.version}`}`;
    const expected = nodes.reduce((s, n) => s + 4 + n.blockSize, 0);
    const r = await this.send(url, { method: "POST", body: nodes.map((n) => n.key).join(","),
                                     headers: this.headers({ "Content-Type": "text/plain" }) }, url);
    const bytes = await this.body(r, expected, url);
    const v = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    const out: Uint8Array[] = [];
    let at = 0;
    for (const n of nodes) {
      if (bytes.length - at < 4) throw new HttpError(`${url}: response ends before node ${n.key}`, true);
      const length = v.getUint32(at, true);
      at += 4;
      if (bytes.length - at < length) throw new HttpError(`${url}: response ends inside node ${n.key}`, true);
      out.push(bytes.slice(at, at + length));
      at += length;
    }
    return out;
  }
}
