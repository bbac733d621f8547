// The toolpath preview: a file's layers drawn from above on a canvas, one layer
// fetched at a time (GET /printer/toolpath/<slug>/<job>/<layer>, binary records:
// per polyline its first command, kind | feature << 8 | speed << 16, its point
// count, then x, y float32 per point). A phone never downloads the G-code.
import { api } from "./api.js";

const TRAVEL = "#9aa0a6";
const DONE_ALPHA = 1;
const TODO_ALPHA = 0.25;
const KEEP_LAYERS = 24;
const CANCELLED = "#c8ccd0";
// Colours by what slicers call their features (PrusaSlicer, Orca, Cura, S3D).
const FEATURE_COLOURS = [
  [/external|outer|wall-outer/i, "#ff7f0e"],
  [/overhang/i, "#0055ff"],
  [/perimeter|wall|inner/i, "#ffc107"],
  [/top|ironing/i, "#e8403a"],
  [/bridge/i, "#4f86c6"],
  [/solid|skin|bottom/i, "#a347c7"],
  [/infill|fill|sparse/i, "#b03029"],
  [/support|interface/i, "#2ca02c"],
  [/skirt|brim|prime|wipe/i, "#17a2b8"],
];

function featureColour(name) {
  for (const [pattern, colour] of FEATURE_COLOURS) if (pattern.test(name)) return colour;
  return "#e37400";
}

function speedColour(speed, low, high) {
  const share = high > low ? Math.min(1, Math.max(0, (speed - low) / (high - low))) : 0.5;
  return `hsl(${Math.round(240 - 240 * share)} 80% 45%)`;
}

/** Polylines of one layer's bytes. */
export function readLayer(buffer) {
  const words = new Uint32Array(buffer);
  const floats = new Float32Array(buffer);
  const lines = [];
  for (let at = 0; at + 3 <= words.length; ) {
    const count = words[at + 2];
    const key = words[at + 1];
    lines.push({
      command: words[at],
      drawn: (key & 0xff) === 1,
      feature: (key >>> 8) & 0xff,
      speed: key >>> 16,
      points: floats.subarray(at + 3, at + 3 + 2 * count),
    });
    at += 3 + 2 * count;
  }
  return lines;
}

/**
 * The preview inside *panel* (a [data-test=preview] section holding a canvas, a
 * layer slider, a travel checkbox and a colour select). `show(slug, jobId)` loads a
 * job's analysis; `follow(job)` follows a printing job's layer and position.
 */
export function toolpathPreview(panel) {
  const $ = (test) => panel.querySelector(`[data-test=${test}]`);
  const canvas = $("preview-canvas");
  const slider = $("preview-layer");
  const label = $("preview-label");
  const travel = $("preview-travel");
  const colour = $("preview-colour");
  const legend = $("preview-legend");
  const followBox = $("preview-follow");
  const context = canvas.getContext("2d");
  let info = null; // {url, layers: [{z, line}], features, bbox}
  let loaded = new Map(); // layer -> polylines
  let shown = -1;
  let doneLine = -1; // commands acknowledged, while the job prints
  let key = "";
  let cancelled = []; // sorted [first, end) command ranges of cancelled objects

  function isCancelled(command) {
    let low = 0, high = cancelled.length;
    while (low < high) {
      const middle = (low + high) >> 1;
      if (cancelled[middle][1] <= command) low = middle + 1;
      else high = middle;
    }
    return low < cancelled.length && cancelled[low][0] <= command;
  }

  function layerOf(line) {
    let found = 0;
    for (let i = 0; i < info.layers.length; i += 1) {
      if (info.layers[i].line <= line) found = i;
      else break;
    }
    return found;
  }

  async function fetchLayer(number) {
    if (loaded.has(number)) return loaded.get(number);
    const response = await fetch(info.url + number, { credentials: "same-origin" });
    if (!response.ok) throw new Error(`layer ${number + 1}: HTTP ${response.status}`);
    const lines = readLayer(await response.arrayBuffer());
    loaded.set(number, lines);
    if (loaded.size > KEEP_LAYERS) loaded.delete(loaded.keys().next().value);
    return lines;
  }

  function transform() {
    const [low, high] = info.bbox;
    const width = canvas.width, height = canvas.height, margin = 12 * devicePixelRatio;
    const scale = Math.min((width - 2 * margin) / Math.max(high[0] - low[0], 1),
      (height - 2 * margin) / Math.max(high[1] - low[1], 1));
    const left = (width - scale * (high[0] - low[0])) / 2;
    const bottom = (height + scale * (high[1] - low[1])) / 2;
    return (x, y) => [left + (x - low[0]) * scale, bottom - (y - low[1]) * scale];
  }

  function strokeLines(lines, place, style) {
    let head = null;
    for (const line of lines) {
      if (!line.drawn && !travel.checked) continue;
      const stroke = style(line);
      if (!stroke) continue;
      context.strokeStyle = stroke.colour;
      context.globalAlpha = stroke.alpha;
      context.lineWidth = (line.drawn ? 1.6 : 0.7) * devicePixelRatio;
      context.beginPath();
      const p = line.points;
      for (let i = 0; i < p.length; i += 2) {
        const [x, y] = place(p[i], p[i + 1]);
        if (i === 0) context.moveTo(x, y);
        else context.lineTo(x, y);
      }
      context.stroke();
      if (stroke.alpha === DONE_ALPHA && p.length >= 2) head = place(p[p.length - 2], p[p.length - 1]);
    }
    return head;
  }

  async function draw(number) {
    if (!info) return;
    number = Math.max(0, Math.min(info.layers.length - 1, number));
    shown = number;
    slider.value = String(number);
    const layer = info.layers[number];
    label.textContent = `Layer ${number + 1} of ${info.layers.length} · Z ${layer.z.toFixed(2)} mm`;
    let lines, below;
    try {
      [lines, below] = await Promise.all([fetchLayer(number), number > 0 ? fetchLayer(number - 1) : []]);
    } catch (error) {
      label.textContent = `${label.textContent} — ${error.message}`;
      return;
    }
    if (shown !== number) return; // the slider moved on meanwhile
    const rect = canvas.getBoundingClientRect();
    canvas.width = Math.round(rect.width * devicePixelRatio);
    canvas.height = Math.round(rect.width * 0.75 * devicePixelRatio);
    context.clearRect(0, 0, canvas.width, canvas.height);
    const place = transform();
    strokeLines(below, place, (line) => (line.drawn ? { colour: "#c8ccd0", alpha: 0.6 } : null));
    const bySpeed = colour.value === "speed";
    const speeds = lines.filter((l) => l.drawn).map((l) => l.speed);
    const low = Math.min(...speeds, Infinity), high = Math.max(...speeds, 0);
    let greyed = 0;
    const head = strokeLines(lines, place, (line) => {
      const alpha = doneLine < 0 || line.command < doneLine ? DONE_ALPHA : TODO_ALPHA;
      if (!line.drawn) return { colour: TRAVEL, alpha };
      if (cancelled.length && isCancelled(line.command)) {
        greyed += 1; // a cancelled object: drawn faint, whatever was printed of it
        return { colour: CANCELLED, alpha: TODO_ALPHA };
      }
      const hue = bySpeed ? speedColour(line.speed, low, high) : featureColour(info.features[line.feature] || "");
      return { colour: hue, alpha };
    });
    context.globalAlpha = 1;
    if (head && doneLine >= 0) {
      context.fillStyle = "#111";
      context.beginPath();
      context.arc(head[0], head[1], 4 * devicePixelRatio, 0, 2 * Math.PI);
      context.fill();
    }
    panel.dataset.layer = String(number + 1); // the layer on the canvas, once drawn
    panel.dataset.drawn = String(lines.length);
    panel.dataset.cancelledDrawn = String(greyed);
    showLegend(bySpeed, low, high, lines);
  }

  function showLegend(bySpeed, low, high, lines) {
    legend.replaceChildren();
    const item = (name, hue) => {
      const span = document.createElement("span");
      span.innerHTML = `<i style="background:${hue}"></i>`;
      span.append(name);
      legend.append(span);
    };
    if (bySpeed) {
      if (high >= low) {
        item(`${low} mm/s`, speedColour(low, low, high));
        item(`${high} mm/s`, speedColour(high, low, high));
      }
      return;
    }
    const used = [...new Set(lines.filter((l) => l.drawn).map((l) => l.feature))];
    for (const feature of used) {
      const name = info.features[feature] || "extrusion";
      item(name, featureColour(name));
    }
  }

  slider.addEventListener("input", () => {
    if (followBox) followBox.checked = false;
    draw(Number(slider.value));
  });
  travel.addEventListener("change", () => draw(shown));
  colour.addEventListener("change", () => draw(shown));
  window.addEventListener("resize", () => draw(shown));

  return {
    async show(slug, jobId) {
      const wanted = `${slug}/${jobId}`;
      if (wanted === key) return info !== null;
      key = wanted;
      info = null;
      loaded = new Map();
      panel.hidden = true;
      const base = `${encodeURIComponent(slug)}/${jobId}`;
      const data = await api("GET", `/printer/analysis/${base}`);
      if (key !== wanted || !data || !data.toolpath || !data.layer_list?.length || !data.bbox) return false;
      info = { url: data.toolpath.url, layers: data.layer_list, features: data.toolpath.features, bbox: data.bbox };
      slider.max = String(info.layers.length - 1);
      panel.hidden = false;
      await draw(doneLine >= 0 ? layerOf(doneLine) : info.layers.length - 1);
      return true;
    },
    follow(job) {
      if (!info || !job) return;
      doneLine = job.lines_acked ?? -1;
      const live = layerOf(doneLine);
      panel.dataset.liveLayer = String(live + 1);
      if (!followBox || followBox.checked) draw(live);
      else if (live === shown) draw(shown);
    },
    stop() {
      doneLine = -1;
      if (info) draw(shown);
    },
    /** Grey the objects named in *names*, given every object's command ranges. */
    cancel(ranges, names) {
      cancelled = names.flatMap((name) => ranges?.[name] ?? []).sort((a, b) => a[0] - b[0]);
      if (info) draw(shown);
    },
  };
}
