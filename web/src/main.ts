// The viewer page, a thin client of the component (viewer.ts): reads the set,
// camera and settings from the URL (?set=URL&camera=ex,ey,ez,tx,ty,tz,ux,uy,uz,fov
// &lod=PX&mode=M&splats=N&color=A&hide=C,..&opacity=A&layers=L&clip=X0,Y0,Z0,X1,Y1,Z1
// &gpu-budget=MIB&block-cache=MIB&edge-aa=off&panel=0&follow=S and #token=T; docs/WEB.md),
// wires the panel and its legends to the component, shows its errors and
// notices, and keeps the URL current. window.surfcast holds the state tests
// and scripts read.

import { formatCamera, parseCamera } from "./camera.js";
import { className } from "./coloring.js";
import { classLegend, rampLegend } from "./legend.js";
import { measure, Measurements, type Tool } from "./measure.js";
import type { Box } from "./lod_selection.js";
import { RendererError } from "./renderer.js";
import { type ColorBy, emptyViewerState, formatBox, kLowPartSuffix, kRenderModes, parseBox, type PickResult, type RenderMode, SurfcastViewer,
         type ViewerOptions, type ViewerState } from "./viewer.js";

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
const params = new URLSearchParams(location.search);
const hash = new URLSearchParams(location.hash.replace(/^#/, ""));

// The page's own errors (its URL, a pick) and the viewer's, shown together.
const pageErrors: string[] = [];
let viewer: SurfcastViewer | undefined;
let exports = 0;
let picked: PickResult | null = null;
let measurements: Measurements | undefined;
const kNotOpen: ViewerState = emptyViewerState();
// The viewer's state, with the page's errors and notices, the clip box as
// ?clip= gives it ("" for none), the LAZ exports downloaded, the surfel last
// picked (null: none, or a click where no splat was) and the measurements
// with their values and labels.
Object.defineProperty(window, "surfcast", { get: () => {
  const s = viewer?.state ?? kNotOpen, clip = viewer?.clip;
  return { ...s, errors: [...pageErrors, ...s.errors],
           clip: clip ? formatBox(clip) : "", exports, picked,
           measurements: (measurements?.list ?? []).map((x) => ({ ...x, ...measure(x.tool, x.points, measurements?.unit) })) };
} });

function showMessages() {
  const { errors, notices } = (window as unknown as { surfcast: ViewerState }).surfcast;
  for (const [id, list] of [["errors", errors], ["notices", notices]] as const) {
    const box = $(id);
    box.textContent = list.join("\n");
    box.hidden = list.length === 0;
  }
}
function showError(message: string) {
  if (!pageErrors.includes(message)) pageErrors.push(message);
  showMessages();
}

function number(name: string, min: number): number | undefined {
  const text = params.get(name);
  if (text === null) return undefined;
  const v = Number(text);
  if (!Number.isFinite(v) || v < min) throw new Error(`?${name}=${text}: expected a number of at least ${min}`);
  return v;
}


// "2,7": ASPRS classes, as surfcast-view's --hide-classes takes them.
function classList(text: string): number[] {
  const classes = text.split(",").filter((s) => s !== "");
  for (const c of classes) if (!/^\d{1,3}$/.test(c) || Number(c) > 255) throw new Error(`?hide=${text}: '${c}' is not a class (0 to 255)`);
  return classes.map(Number);
}

// Keeps the URL current, so that it can be shared.
function updateUrl(name: string, value: string) {
  const url = new URL(location.href);
  if (value) url.searchParams.set(name, value);
  else url.searchParams.delete(name);
  history.replaceState(null, "", url);
}

function options(): ViewerOptions {
  const mode = params.get("mode") ?? undefined;
  if (mode !== undefined && !kRenderModes.includes(mode as RenderMode))
    throw new Error(`?mode=${mode}: expected ${kRenderModes.slice(0, -1).join(", ")} or ${kRenderModes.at(-1)}`);
  const opacity = number("opacity", 0), layers = number("layers", 1);
  const clip = params.get("clip");
  const camera = params.get("camera");
  return {
    token: hash.get("token") ?? undefined,
    camera: camera ? parseCamera(camera) : undefined,
    detail: number("lod", 0.01),
    splatBudget: number("splats", 1),
    gpuBudgetMiB: number("gpu-budget", 1),
    blockCacheMiB: number("block-cache", 0),
    mode: mode as RenderMode | undefined,
    colorBy: (params.get("color") ?? "auto") as ColorBy,
    hiddenClasses: classList(params.get("hide") ?? ""),
    clip: clip !== null ? parseBox(clip, "?clip=") : undefined,
    opacity,
    layers,
    edgeAA: params.get("edge-aa") !== "off",
    forbidFloatBlend: params.get("floatblend") === "off",
    follow: number("follow", 0.1),
  };
}

// The panel: hidden by ?panel=0 (embedding, screenshots), collapsible; the
// help overlay from its "?" button or the "?" key, closed by Esc.
function panelControls() {
  if (params.get("panel") === "0") document.body.classList.add("nopanel");
  const collapse = $("collapse"), help = $("help");
  collapse.onclick = () => collapse.setAttribute("aria-expanded", String(!document.body.classList.toggle("panel-collapsed")));
  $("help-button").onclick = () => (help.hidden = !help.hidden);
  $("help-close").onclick = () => (help.hidden = true);
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    if (e.key === "?") help.hidden = !help.hidden;
    else if (e.key === "Escape") help.hidden = true;
  });
}

// Mode, detail, splat budget, colouring and its legend, classes, the clip
// box and its download, the screenshot.
function wirePanel(v: SurfcastViewer, setUrl: string) {
  const info = v.info;
  const modeSelect = $<HTMLSelectElement>("mode");
  modeSelect.value = v.mode;
  modeSelect.onchange = () => v.setMode(modeSelect.value as RenderMode);
  // Detail: a number, and a slider over 0.25 to 8 pixels in quarter octaves.
  const lodInput = $<HTMLInputElement>("lod"), lodSlider = $<HTMLInputElement>("lod-slider");
  const showDetail = () => {
    lodInput.value = String(v.detail);
    lodSlider.value = String(Math.log2(v.detail));
  };
  showDetail();
  lodInput.onchange = () => {
    const px = Number(lodInput.value);
    if (px > 0 && Number.isFinite(px)) v.setDetail(px);
    showDetail();
  };
  lodSlider.oninput = () => (v.setDetail(2 ** Number(lodSlider.value)), showDetail());
  const budgetInput = $<HTMLInputElement>("splats");
  budgetInput.value = String(v.splatBudget);
  budgetInput.onchange = () => {
    const n = Number(budgetInput.value);
    if (n >= 1 && Number.isFinite(n)) v.setSplatBudget(n);
    budgetInput.value = String(v.splatBudget);
  };

  const colorSelect = $<HTMLSelectElement>("color");
  for (const by of v.colorings) colorSelect.add(new Option(by, by, false, by === v.colorBy));
  colorSelect.onchange = () => {
    v.setColorBy(colorSelect.value as ColorBy);
    rampLegend($("ramp"), v.colorBy, info);
    updateUrl("color", v.colorBy);
  };
  rampLegend($("ramp"), v.colorBy, info);
  const showClasses = () => classLegend($("classes"), info.statistics.classCounts, v.hiddenClasses, (hidden) => {
    v.setHiddenClasses(hidden);
    updateUrl("hide", hidden.join(","));
    showClasses();
  });
  showClasses();

  // The clip box: numbers in the set's own coordinates; the set's bounds
  // until one is given. Invalid numbers are marked and not applied.
  const clipOn = $<HTMLInputElement>("clip-on");
  const clipInputs = ["x0", "y0", "z0", "x1", "y1", "z1"].map((id) => $<HTMLInputElement>(`clip-${id}`));
  const shown = v.clip ?? { min: info.boundsMin, max: info.boundsMax };
  clipInputs.forEach((input, i) => (input.value = String(i < 3 ? shown.min[i] : shown.max[i - 3])));
  clipOn.checked = v.clip !== undefined;
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
    v.setClip(clipOn.checked ? box : undefined);
    updateUrl("clip", v.clip ? formatBox(v.clip) : "");
  };
  for (const input of [clipOn, ...clipInputs]) input.onchange = applyClip;
  const download = $<HTMLButtonElement>("download");
  download.onclick = async () => {
    const box = clipOn.checked ? readClip() : undefined;
    if (clipOn.checked && !box) return;
    download.disabled = true;
    download.textContent = "exporting…";
    try {
      const blob = await v.exportLaz(box);
      const link = document.createElement("a");
      link.download = `${new URL(setUrl).pathname.split("/").filter((s) => s).pop() ?? "points"}.laz`;
      link.href = URL.createObjectURL(blob);
      link.click();
      setTimeout(() => URL.revokeObjectURL(link.href), 60000);
      ++exports;
    } catch {
      // The viewer's "error" event has shown it.
    } finally {
      download.disabled = false;
      download.textContent = "download points (LAZ)";
    }
  };
  wireInspect(v);
  $("screenshot").onclick = () => {
    const link = document.createElement("a");
    link.download = "surfcast.png";
    link.href = v.canvas.toDataURL("image/png");
    link.click();
  };
}

// A click (a press and release within 4 px, no drag) picks the surfel under
// the cursor: its attributes go in the panel, and with a measuring tool its
// centre is the measurement's next point. A double click or Enter ends a
// polyline or an area.
function wireInspect(v: SurfcastViewer) {
  // Projected relative to the set's centre, so that georeferenced sets keep their precision.
  const centre = [0, 1, 2].map((a) => 0.5 * (v.info.boundsMin[a] + v.info.boundsMax[a])) as [number, number, number];
  const m = measurements = new Measurements(v.canvas, centre, params.get("units") ?? "");
  const tool = $<HTMLSelectElement>("tool");
  const table = $<HTMLTableElement>("picked");
  const redraw = () => m.draw(v.camera);
  v.addEventListener("camera", redraw);
  new ResizeObserver(redraw).observe(v.canvas);  // the window, or the panel beside the view
  $("clear-measurements").onclick = () => {
    m.clear();
    redraw();
  };
  // Picks and ends run one at a time, in the order they came; a step's
  // failure is shown and the next runs.
  let queue: Promise<void> = Promise.resolve();
  const enqueue = (step: () => void | Promise<void>) => {
    queue = queue.then(step).catch((err) => showError(`pick: ${(err as Error).message}`));
  };
  const finish = () => enqueue(() => {
    m.finish();
    redraw();
  });
  v.canvas.addEventListener("dblclick", finish);
  window.addEventListener("keydown", (e) => e.key === "Enter" && !(e.target instanceof HTMLInputElement) && finish());
  let down: { x: number; y: number } | null = null;
  v.canvas.addEventListener("pointerdown", (e) => (down = e.button === 0 ? { x: e.offsetX, y: e.offsetY } : null));
  v.canvas.addEventListener("click", (e) => {
    const moved = !down || Math.hypot(e.offsetX - down.x, e.offsetY - down.y) > 4;
    down = null;
    if (moved || e.detail >= 2) return;  // a drag, or a double click's second click (dblclick ends the measurement)
    const [x, y, measuring] = [e.offsetX, e.offsetY, tool.value as Tool | "pick"];
    enqueue(async () => {
      const hit = await v.pick(x, y);
      picked = hit;
      showPicked(table, hit, v);
      if (hit && measuring !== "pick") {
        m.add(measuring, hit.position);
        redraw();
      }
    });
  });
}

// The picked surfel's attributes: position in the set's coordinates, colour,
// class by name, returns, and every other attribute the set stores.
function showPicked(table: HTMLTableElement, hit: PickResult | null, v: SurfcastViewer) {
  const rows: [string, string][] = [];
  if (!hit) rows.push(["", "no point there (or the view is still changing)"]);
  else {
    const a = { ...hit.attributes };
    rows.push(["x, y, z", hit.position.map((c) => c.toFixed(4)).join(", ")]);
    if (hit.color) rows.push(["colour", hit.color.join(", ")]);
    if ("classification" in a) rows.push(["class", `${a.classification} ${className(a.classification)}`]);
    if ("return_number" in a) rows.push(["return", `${a.return_number} of ${a.number_of_returns ?? "?"}`]);
    for (const name of ["classification", "return_number", "number_of_returns"]) delete a[name];
    for (const [name, value] of Object.entries(a)) {
      const step = v.info.attributes.find((x) => x.name === name + kLowPartSuffix || x.name === name)?.scale ?? 1;  // a wide field's finer step first
      rows.push([name.replaceAll("_", " "), value.toFixed(Math.max(0, Math.min(9, Math.ceil(-Math.log10(step)))))]);
    }
    rows.push(["radius", hit.radius.toPrecision(3)]);
    rows.push(["node", hit.node]);
  }
  table.replaceChildren(...rows.map(([k, value]) => {
    const tr = document.createElement("tr");
    tr.insertCell().textContent = k;
    tr.insertCell().textContent = value;
    return tr;
  }));
  table.hidden = false;
}

async function main() {
  panelControls();
  const setParam = params.get("set");
  if (!setParam) {
    $("intro").hidden = false;
    return;
  }
  const setUrl = new URL(setParam, location.href).href;
  let opts: ViewerOptions;
  try {
    opts = options();
  } catch (e) {
    showError((e as Error).message);
    return;
  }
  try {
    viewer = await SurfcastViewer.open($<HTMLCanvasElement>("view"), setUrl, opts);
  } catch (e) {
    showError(e instanceof RendererError ? e.message : `cannot open ${setUrl}: ${(e as Error).message}`);
    return;
  }
  const v = viewer;
  for (const type of ["error", "notice"]) v.addEventListener(type, showMessages);
  showMessages();
  v.addEventListener("camera", () => updateUrl("camera", formatCamera(v.camera)));
  updateUrl("camera", formatCamera(v.camera));
  const progress = () => {
    const s = v.state;
    $("progress").textContent = `${s.nodes} nodes, ${s.splats.toLocaleString()} splats, ` +
      `${(s.bytes / 1e6).toFixed(1)} MB in ${s.requests} requests` + (s.converged ? ", converged" : `, ${s.inFlight} in flight`) +
      (opts.follow ? `; version ${s.version}${s.loadingVersion ? ", loading the next" : ""}` : "") +
      (s.preview ? `; a preview of a build in progress (1 in ${s.preview} points` +
                   (s.previewDone > 0 ? `, ${Math.floor(100 * s.previewDone)} % at full detail)` : ")") : "");
  };
  for (const type of ["change", "converged", "version"]) v.addEventListener(type, progress);
  wirePanel(v, setUrl);
  // For benchmarks (bench/browser_bench.mjs).
  Object.assign(window, { surfcastTimeFrames: (n: number) => v.timeFrames(n), surfcastPick: (x: number, y: number) => v.pick(x, y) });
}

main().catch((e) => showError(`viewer: ${(e as Error).message}`));
