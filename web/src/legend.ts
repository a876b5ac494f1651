// The panel's legends: the classes a set holds, with their ASPRS names,
// point counts (tileset.json's statistics), colours, toggles and "only this";
// and the current colouring's palette as a bar with its range in the set's
// units. Pure DOM: the page owns the state and redraws on changes.

import { classColor, className, type ColorBy, intensityColor, type RGB, returnColor, viridis } from "./coloring.js";
import type { TilesetInfo } from "./format.js";

const css = (c: RGB) => `rgb(${c.map((v) => Math.round(v * 255)).join(",")})`;

function element<K extends keyof HTMLElementTagNameMap>(tag: K, props: Partial<HTMLElementTagNameMap[K]> = {},
                                                         ...children: (Node | string)[]): HTMLElementTagNameMap[K] {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
}

// One row per class in `counts`, ascending: a toggle, the colour, "N name"
// and the count, and "only" (every other class hidden). `setHidden` gets the
// classes to hide after a click.
export function classLegend(container: HTMLElement, counts: Map<number, number>, hidden: number[],
                            setHidden: (hidden: number[]) => void) {
  const classes = [...counts.keys()].sort((a, b) => a - b);
  container.replaceChildren();
  for (const c of classes) {
    const box = element("input", { type: "checkbox", checked: !hidden.includes(c) });
    box.onchange = () => setHidden(box.checked ? hidden.filter((h) => h !== c) : [...hidden, c]);
    const only = element("button", { type: "button", className: "only", title: `show class ${c} alone` }, "only");
    only.onclick = () => setHidden(classes.filter((k) => k !== c));
    container.append(element("div", { className: "class" },
      element("label", {}, box, element("span", { className: "swatch", style: `background: ${css(classColor(c))}` } as never),
              ` ${c} ${className(c)}`),
      element("span", { className: "count" }, counts.get(c)!.toLocaleString("en-US")), only));
  }
  if (hidden.length) {
    const all = element("button", { type: "button" }, "show all");
    all.onclick = () => setHidden([]);
    container.append(all);
  }
}

// The palette of `by` as a bar from its low to its high end, labelled with
// the range it spans (elevation in the set's units, intensity's 2-98 %
// range), or the return classes' swatches; nothing for rgb and classes
// (their legend is the class list).
export function rampLegend(container: HTMLElement, by: ColorBy, info: TilesetInfo) {
  container.replaceChildren();
  const st = info.statistics;
  const bar = (colour: (t: number) => RGB, low: number, high: number, what: string) => {
    const stops = Array.from({ length: 11 }, (_, i) => `${css(colour(i / 10))} ${i * 10}%`);
    const digits = Math.max(0, Math.min(3, 2 - Math.floor(Math.log10(Math.abs(high - low) || 1))));
    container.append(element("div", { className: "ramp", style: `background: linear-gradient(to right, ${stops.join(", ")})` } as never),
                     element("div", { className: "range" }, element("span", {}, low.toFixed(digits)),
                             element("span", {}, what), element("span", {}, high.toFixed(digits))));
  };
  if (by === "elevation") {
    bar(viridis, st.elevationMin, st.elevationMax, "elevation");
  } else if (by === "intensity" && st.intensity) {
    const { p2, p98 } = st.intensity;
    bar((t) => intensityColor(p2 + t * (p98 - p2), p2, p98), p2, p98, "intensity (2-98 %)");
  } else if (by === "return") {
    for (const [name, number, count] of [["single", 1, 1], ["first", 1, 2], ["intermediate", 2, 3], ["last", 2, 2]] as const)
      container.append(element("span", { className: "return" },
        element("span", { className: "swatch", style: `background: ${css(returnColor(number, count))}` } as never), ` ${name} `));
  }
}
