// The viewer page: reads the set, camera and settings from the URL
// (?set=URL&camera=ex,ey,ez,tx,ty,tz,ux,uy,uz,fov&lod=PX&mode=M&splats=N&color=A&hide=C,..
// &opacity=A&layers=L&clip=X0,Y0,Z0,X1,Y1,Z1&panel=0 and #token=T; docs/WEB.md), streams the set and redraws as
// blocks arrive or the camera moves. window.surfcast holds the state tests and scripts read.

import { type Camera, formatCamera, frameBox, parseCamera, viewportScale, viewRows } from "./camera.js";
import { type ColorBy, kColorByOrder, resolveColorBy } from "./coloring.js";
import { Controls } from "./controls.js";
import { classLegend, rampLegend } from "./legend.js";
import { crc32 } from "./crc32.js";
import { type Box, emptyStats } from "./lod_selection.js";
import { attribute } from "./format.js";
import { type DrawnNode, kDefaultEdgeTau, kDefaultLayers, kDefaultLowpassVariance, kDefaultZt, kMaxLayers, kNearFraction,
         type RenderMode, type RenderSettings, RendererError, SplatRenderer } from "./renderer.js";
import { TileSource } from "./source.js";
import { coloringFor, kDefaultStreamOptions, Streamer } from "./streamer.js";

interface State {
  converged: boolean;
  nodes: number;
  // CRC-32 of the drawn nodes' keys in key order, joined by commas:
  // surfcast-view's nodes_crc where both draw the same nodes.
  nodesCrc: number;
  splats: number;
  bytes: number;
  requests: number;
  errors: string[];
  notices: string[];
  mode: string;
  firstImageMs: number | null;
  convergedMs: number | null;
  resident: number; // nodes resident on the GPU (drawn or kept for later views)
  residentBytes: number; // the resident nodes' surfels, 32 bytes each in whole granules (lod_selection.ts)
  keptBytes: number; // the resident nodes' compressed blocks, kept for recolouring (within ?block-cache)
  refetched: number; // blocks fetched again for a recolouring (their kept copies had gone)
  evictions: number;
  frames: number;
  frameMs: number; // the last frame's time on the GPU, from its draw to its fence
  camera: string;
  clip: string; // the clip box as ?clip= gives it, "" for none
  exports: number; // LAZ exports of the clip box downloaded
}

const state: State = { converged: false, nodes: 0, nodesCrc: 0, splats: 0, bytes: 0, requests: 0, errors: [], notices: [], mode: "",
                       firstImageMs: null, convergedMs: null, resident: 0, residentBytes: 0, keptBytes: 0, refetched: 0,
                       evictions: 0, frames: 0, frameMs: 0, camera: "", clip: "", exports: 0 };
(window as unknown as { surfcast: State }).surfcast = state;

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
const params = new URLSearchParams(location.search);
const hash = new URLSearchParams(location.hash.replace(/^#/, ""));

function showError(message: string) {
  if (!state.errors.includes(message)) state.errors.push(message);
  const box = $("errors");
  box.textContent = state.errors.join("\n");
  box.hidden = false;
}
function showNotice(message: string) {
  if (!state.notices.includes(message)) state.notices.push(message);
  const box = $("notices");
  box.textContent = state.notices.join("\n");
  box.hidden = false;
}

function number(name: string, fallback: number, min: number): number {
  const text = params.get(name);
  if (text === null) return fallback;
  const v = Number(text);
  if (!Number.isFinite(v) || v < min) throw new Error(`?${name}=${text}: expected a number of at least ${min}`);
  return v;
}

// "X0,Y0,Z0,X1,Y1,Z1", as surfcast-view's --clip takes it; `what` names it in errors.
function parseBox(text: string, what: string): Box {
  const v = text.split(",").map((s) => (s.trim() === "" ? NaN : Number(s)));
  if (v.length !== 6 || !v.every(Number.isFinite))
    throw new Error(`${what} ${text}: six numbers wanted (xmin,ymin,zmin,xmax,ymax,zmax)`);
  const box: Box = { min: [v[0], v[1], v[2]], max: [v[3], v[4], v[5]] };
  for (let a = 0; a < 3; ++a)
    if (box.min[a] > box.max[a]) throw new Error(`${what} ${text}: its minimum exceeds its maximum on axis ${"xyz"[a]}`);
  return box;
}
const formatBox = (b: Box) => [...b.min, ...b.max].join(",");

function normalsOriented(source: string): boolean {
  return source !== "" && source.split("+").every((p) => p === "input" || p === "estimated-scan-origin");
}

// The panel: hidden by ?panel=0 (embedding, screenshots), collapsible; the
// help overlay from its "?" button or the "?" key, closed by Esc.
function panelControls() {
  if (params.get("panel") === "0") document.body.classList.add("nopanel");
  const panel = $("panel"), collapse = $("collapse"), help = $("help");
  collapse.onclick = () => collapse.setAttribute("aria-expanded", String(!panel.classList.toggle("collapsed")));
  $("help-button").onclick = () => (help.hidden = !help.hidden);
  $("help-close").onclick = () => (help.hidden = true);
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    if (e.key === "?") help.hidden = !help.hidden;
    else if (e.key === "Escape") help.hidden = true;
  });
}

async function main() {
  panelControls();
  const setParam = params.get("set");
  if (!setParam) {
    $("intro").hidden = false;
    return;
  }
  const canvas = $<HTMLCanvasElement>("view");
  const setUrl = new URL(setParam, location.href).href;
  let renderer: SplatRenderer;
  try {
    renderer = new SplatRenderer(canvas, { forbidFloatBlend: params.get("floatblend") === "off" });
  } catch (e) {
    showError((e as Error).message);
    return;
  }
  const targetPixels = number("lod", 1, 0.01);
  const splatBudget = number("splats", 5_000_000, 1);
  const source = new TileSource(setUrl, { token: hash.get("token") ?? undefined });
  let hidden = (params.get("hide") ?? "").split(",").filter((s) => s !== "").map(Number);
  let colorBy = (params.get("color") ?? "auto") as ColorBy;
  const workerUrl = new URL("decode_worker.js", document.baseURI);
  let streamer: Streamer<DrawnNode>;
  try {
    streamer = await Streamer.open(source, renderer, workerUrl, (info, origin) => {
      const by = resolveColorBy(colorBy, info);
      if (!kColorByOrder.includes(by as ColorBy)) throw new Error(by);
      colorBy = by as ColorBy;
      return coloringFor(info, origin, colorBy, hidden);
    }, { ...kDefaultStreamOptions, memoryBudget: number("gpu-budget", 512, 1) * 2 ** 20,
         keptBudget: number("block-cache", 256, 0) * 2 ** 20 });
  } catch (e) {
    showError(`cannot open ${setUrl}: ${(e as Error).message}`);
    return;
  }
  const info = streamer.info;
  const hasWeights = info.weights !== "none";
  const settings: RenderSettings = {
    mode: (params.get("mode") ?? "ewa-pixel") as RenderMode,
    shading: colorBy === "rgb" || colorBy === "intensity" ? "unlit" : "lambert",
    kernelScale: info.kernelScale,
    cutoff: 1,
    zt: kDefaultZt,
    lowpassVariance: kDefaultLowpassVariance,
    edgeAA: params.get("edge-aa") !== "off",
    edgeTau: kDefaultEdgeTau,
    background: [1, 1, 1],
    backfaceCull: normalsOriented(info.normalSource),
    translucent: attribute(info, "opacity") !== undefined,
    opacity: number("opacity", 1, 0),
    layers: number("layers", kDefaultLayers, 1),
  };
  try {
    const clip = params.get("clip");
    if (clip !== null) settings.clip = parseBox(clip, "?clip=");
  } catch (e) {
    showError((e as Error).message);
    return;
  }
  if (settings.opacity > 1 || settings.layers > kMaxLayers || !Number.isInteger(settings.layers)) {
    showError(`?opacity= is in [0, 1] and ?layers= a whole number in [1, ${kMaxLayers}]`);
    return;
  }
  if (!["points", "circles", "ewa-noprefilter", "ewa-surfel", "ewa-pixel"].includes(settings.mode)) {
    showError(`?mode=${settings.mode}: expected points, circles, ewa-noprefilter, ewa-surfel or ewa-pixel`);
    return;
  }
  const drawn = () => renderer.effectiveMode(settings.mode, hasWeights);
  const noteMode = () => {
    state.mode = drawn();
    if ((settings.translucent || settings.opacity < 1) && !renderer.floatBlend)
      showNotice("this browser cannot blend float targets (EXT_float_blend): transparency is drawn opaque");
    if (state.mode !== settings.mode)
      showNotice(`this browser cannot blend float targets (EXT_float_blend): drawing ${state.mode} instead of ${settings.mode}` +
                 (hasWeights ? "" : ", as the set was built without weights (surfcast-build --weights analytic)"));
  };
  noteMode();

  const size = () => {
    const dpr = window.devicePixelRatio || 1;
    return [Math.max(1, Math.round(canvas.clientWidth * dpr)), Math.max(1, Math.round(canvas.clientHeight * dpr))];
  };
  let [width, height] = size();
  let camera: Camera;
  try {
    const text = params.get("camera");
    camera = text ? parseCamera(text) : frameBox(info.boundsMin, info.boundsMax, width / height);
  } catch (e) {
    showError((e as Error).message);
    return;
  }

  // Redraws: one frame on the GPU at a time (a fence says when it is done),
  // as soon as the GPU is free when the camera moves, and while blocks
  // stream in no more often than every other frame's cost, so that a slow
  // WebGL (SwiftShader takes about a second for half a million splats)
  // spends its time decoding, not redrawing. The state says converged once
  // the converged frame is done, and not converged from the moment the user
  // changes the view (camera, settings, colouring) until then.
  let dirty = true, urgent = true, lastDraw = -Infinity, frameCost = 0;
  let fence: WebGLSync | null = null, fenceConverged = false;
  const start = performance.now();
  streamer.onChange = () => (dirty = true);
  const changed = () => {
    urgent = dirty = true;
    state.converged = false;
  };
  // Keeps the URL current, so that it can be shared.
  const updateUrl = (name: string, value: string) => {
    const url = new URL(location.href);
    if (value) url.searchParams.set(name, value);
    else url.searchParams.delete(name);
    history.replaceState(null, "", url);
  };
  const setCamera = (c: Camera) => {
    changed();
    camera = c;
    state.camera = formatCamera(c);
    updateUrl("camera", state.camera);
  };
  setCamera(camera);
  new Controls(canvas, () => camera, setCamera);

  // Interface: mode, level of detail, splat budget, colouring, classes.
  const modeSelect = $<HTMLSelectElement>("mode");
  modeSelect.value = settings.mode;
  modeSelect.onchange = () => {
    settings.mode = modeSelect.value as RenderMode;
    noteMode();
    changed();
  };
  const lodInput = $<HTMLInputElement>("lod");
  lodInput.value = String(targetPixels);
  const budgetInput = $<HTMLInputElement>("splats");
  budgetInput.value = String(splatBudget);
  for (const input of [lodInput, budgetInput]) input.onchange = changed;
  const colorSelect = $<HTMLSelectElement>("color");
  for (const by of kColorByOrder) {
    if (resolveColorBy(by, info) !== by) continue;
    colorSelect.add(new Option(by, by, false, by === colorBy));
  }
  const recolor = () => {
    changed();
    streamer.recolor(coloringFor(info, streamer.origin, colorBy, hidden));
  };
  colorSelect.onchange = () => {
    colorBy = colorSelect.value as ColorBy;
    settings.shading = colorBy === "rgb" || colorBy === "intensity" ? "unlit" : "lambert";
    rampLegend($("ramp"), colorBy, info);
    updateUrl("color", colorBy);
    recolor();
  };
  const showClasses = () => classLegend($("classes"), info.statistics.classCounts, hidden, (h) => {
    hidden = h;
    updateUrl("hide", hidden.join(","));
    showClasses();
    recolor();
  });
  showClasses();
  rampLegend($("ramp"), colorBy, info);
  // The clip box: numbers in the set's own coordinates; the set's bounds
  // until one is given. Invalid numbers are marked and not applied.
  const clipOn = $<HTMLInputElement>("clip-on");
  const clipInputs = ["x0", "y0", "z0", "x1", "y1", "z1"].map((id) => $<HTMLInputElement>(`clip-${id}`));
  const shownBox = settings.clip ?? { min: info.boundsMin, max: info.boundsMax };
  clipInputs.forEach((input, i) => (input.value = String(i < 3 ? shownBox.min[i] : shownBox.max[i - 3])));
  clipOn.checked = settings.clip !== undefined;
  state.clip = settings.clip ? formatBox(settings.clip) : "";
  const readClip = (): Box | undefined => {
    try {
      const box = parseBox(clipInputs.map((input) => input.value).join(","), "clip box");
      clipInputs.forEach((input) => input.setCustomValidity(""));
      return box;
    } catch (e) {
      clipInputs.forEach((input) => input.setCustomValidity((e as Error).message));
      return undefined;
    }
  };
  const applyClip = () => {
    const box = readClip();
    if (!box) return;
    settings.clip = clipOn.checked ? box : undefined;
    state.clip = settings.clip ? formatBox(settings.clip) : "";
    updateUrl("clip", state.clip);
    changed();
  };
  for (const input of [clipOn, ...clipInputs]) input.onchange = applyClip;
  // The points in the box (the set's bounds when no box is on) of the
  // classes shown, as LAZ, from surfcast-serve's export route.
  const download = $<HTMLButtonElement>("download");
  download.onclick = async () => {
    const box = clipOn.checked ? readClip() : { min: info.boundsMin, max: info.boundsMax };
    if (!box) return;
    const shown = hidden.length ? [...info.statistics.classCounts.keys()].filter((c) => !hidden.includes(c)) : undefined;
    download.disabled = true;
    download.textContent = "exporting…";
    try {
      const blob = await source.exportLaz(box, shown);
      const link = document.createElement("a");
      link.download = `${new URL(setUrl).pathname.split("/").filter((s) => s).pop() ?? "points"}.laz`;
      link.href = URL.createObjectURL(blob);
      link.click();
      setTimeout(() => URL.revokeObjectURL(link.href), 60000);
      ++state.exports;
    } catch (e) {
      showError(`export: ${(e as Error).message}`);
    } finally {
      download.disabled = false;
      download.textContent = "download points (LAZ)";
    }
  };

  $("screenshot").onclick = () => {
    const link = document.createElement("a");
    link.download = "surfcast.png";
    link.href = canvas.toDataURL("image/png");
    link.click();
  };

  let drawLast = () => {};
  // For benchmarks: draws the current selection n times, each waited for
  // (a one-pixel read: gl.finish does not wait in Chromium), and returns the
  // mean milliseconds per frame.
  (window as unknown as { surfcastTimeFrames: (n: number) => number }).surfcastTimeFrames = (n: number) => {
    const gl = renderer.gl, pixel = new Uint8Array(4);
    const sync = () => gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
    drawLast();
    sync();
    const t0 = performance.now();
    for (let i = 0; i < n; ++i) {
      drawLast();
      sync();
    }
    return (performance.now() - t0) / n;
  };

  // Each animation frame: a new selection (which also queues the fetches the
  // view needs) whenever something changed, and a draw of the latest one
  // when the GPU is free and the pacing allows. Selecting never waits for
  // drawing: on a slow WebGL the stream keeps going while a frame renders.
  let selection: { gpu: DrawnNode[]; splats: number; converged: boolean; nodesCrc: number } | null = null;
  const select = () => {
    const lod = emptyStats();
    const lodTarget = Number(lodInput.value) > 0 ? Number(lodInput.value) : targetPixels;
    const budget = Number(budgetInput.value) >= 1 ? Number(budgetInput.value) : splatBudget;
    const selected = streamer.update(camera, width, height, { targetPixels: lodTarget, frustumCulling: true,
      backfaceCulling: settings.backfaceCull, splatBudget: budget, memoryBudget: Infinity, clip: settings.clip }, lod);
    // Drawn in key order, as the Vulkan client draws them. Every selected
    // node is resident until the next update (eviction spares what a view uses).
    const nodes = streamer.selector.nodes;
    selected.sort((a, b) => {
      const p = nodes[a.index], q = nodes[b.index];
      return p.level - q.level || p.x - q.x || p.y - q.y || p.z - q.z;
    });
    const gpu: DrawnNode[] = [];
    const keys: string[] = [];
    let splats = 0;
    for (const s of selected) {
      const r = streamer.residentNode(s.index);
      if (!r) continue;
      gpu.push(r.gpu);
      keys.push(nodes[s.index].key);
      splats += r.count;
    }
    const st = streamer.stats;
    const converged = !st.gaveUp && lod.missing.length === 0 && lod.missingPages.length === 0 && st.inFlight === 0;
    if (st.gaveUp) showError(st.lastError);
    Object.assign(state, { bytes: st.bytes, requests: st.requests, resident: st.resident, residentBytes: st.residentBytes,
                           keptBytes: st.keptBytes, refetched: st.refetched, evictions: st.evictions });
    $("progress").textContent = `${gpu.length} nodes, ${splats.toLocaleString()} splats, ` +
      `${(st.bytes / 1e6).toFixed(1)} MB in ${st.requests} requests` + (converged ? ", converged" : `, ${st.inFlight} in flight`);
    return { gpu, splats, converged, nodesCrc: crc32(new TextEncoder().encode(keys.join(","))) };
  };

  const frame = (now: number) => {
    const gl = renderer.gl;
    if (fence && gl.getSyncParameter(fence, gl.SYNC_STATUS) === gl.SIGNALED) {
      gl.deleteSync(fence);
      fence = null;
      frameCost = performance.now() - lastDraw;
      state.frameMs = frameCost;
      if (fenceConverged && !dirty && !selection) {
        state.convergedMs ??= performance.now() - start;
        state.converged = true;
      }
    }
    const [w, h] = size();
    if (w !== width || h !== height) {
      [width, height] = [w, h];
      urgent = dirty = true;
    }
    if (dirty) {
      dirty = false;
      state.converged = false;
      selection = select();
    }
    if (selection && !fence && (urgent || now - lastDraw >= 2 * frameCost)) {
      urgent = false;
      if (canvas.width !== width || canvas.height !== height) {
        canvas.width = width;
        canvas.height = height;
      }
      const { gpu, splats, converged, nodesCrc } = selection;
      selection = null;
      const eta = viewportScale(camera, height);
      const rows = viewRows(camera, streamer.origin);
      const diagonal = Math.hypot(info.boundsMax[0] - info.boundsMin[0], info.boundsMax[1] - info.boundsMin[1],
                                  info.boundsMax[2] - info.boundsMin[2]);
      const eye = Math.hypot(rows[3], rows[7], rows[11]);
      const near = Math.max(diagonal, eye) * kNearFraction || kNearFraction;
      const view = { rows, eta, near, origin: streamer.origin };
      drawLast = () => renderer.render(gpu, view, settings, hasWeights);
      drawLast();
      lastDraw = performance.now();
      fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
      gl.flush();
      fenceConverged = converged;
      ++state.frames;
      Object.assign(state, { nodes: gpu.length, nodesCrc, splats });
      if (gpu.length && state.firstImageMs === null) state.firstImageMs = performance.now() - start;
    }
    requestAnimationFrame(frame);
  };
  requestAnimationFrame(frame);
}

main().catch((e) => showError(e instanceof RendererError ? e.message : `viewer: ${(e as Error).message}`));
