// A small SVG line chart of temperatures: current as solid lines, targets dashed.
const COLORS = ["#d93025", "#1a73e8", "#188038", "#e37400", "#9334e6", "#007b83"];
const W = 600, H = 240, LEFT = 40, BOTTOM = 24, TOP = 8, RIGHT = 8;

export class TempChart {
  /** *root* holds an <svg> and a .legend; *minutes* is the window shown. */
  constructor(root, minutes = 30) {
    this.svg = root.querySelector("svg");
    this.legend = root.querySelector(".legend");
    this.windowMs = minutes * 60 * 1000;
    this.points = []; // {t: ms, temps: {...}}
  }

  add(time, temperatures) {
    const t = typeof time === "number" ? time : Date.parse(time);
    if (!Number.isFinite(t) || !temperatures) return;
    this.points.push({ t, temps: temperatures });
    const since = Date.now() - this.windowMs;
    while (this.points.length && this.points[0].t < since) this.points.shift();
  }

  draw() {
    const now = Date.now();
    const start = now - this.windowMs;
    const names = [...new Set(this.points.flatMap((p) => Object.keys(p.temps)))].sort();
    let top = 50;
    for (const p of this.points) {
      for (const r of Object.values(p.temps)) {
        top = Math.max(top, r?.current ?? 0, r?.target ?? 0);
      }
    }
    top = Math.ceil((top + 10) / 50) * 50;
    const x = (t) => LEFT + ((t - start) / this.windowMs) * (W - LEFT - RIGHT);
    const y = (v) => TOP + (1 - v / top) * (H - TOP - BOTTOM);
    const parts = [];
    for (let v = 0; v <= top; v += top / 5) {
      parts.push(`<line class="axis" x1="${LEFT}" x2="${W - RIGHT}" y1="${y(v)}" y2="${y(v)}"/>`);
      parts.push(`<text x="2" y="${y(v) + 4}">${Math.round(v)}</text>`);
    }
    for (let m = 0; m * 60000 <= this.windowMs; m += 10) {
      const label = m === 0 ? "now" : `−${m} min`;
      parts.push(`<text x="${x(now - m * 60000) - (m === 0 ? 34 : 30)}" y="${H - 4}">${label}</text>`);
    }
    names.forEach((name, i) => {
      const color = COLORS[i % COLORS.length];
      for (const key of ["current", "target"]) {
        const coords = this.points
          .filter((p) => typeof p.temps[name]?.[key] === "number")
          .map((p) => `${x(p.t).toFixed(1)},${y(p.temps[name][key]).toFixed(1)}`);
        if (coords.length) {
          const dash = key === "target" ? ' stroke-dasharray="6 4"' : "";
          parts.push(`<polyline fill="none" stroke="${color}" stroke-width="2"${dash} points="${coords.join(" ")}"/>`);
        }
      }
    });
    this.svg.innerHTML = parts.join("");
    this.legend.replaceChildren(
      ...names.map((name, i) => {
        const span = document.createElement("span");
        span.style.setProperty("--c", COLORS[i % COLORS.length]);
        span.textContent = `${name} (dashed: target)`;
        return span;
      }),
    );
    if (!names.length) this.legend.textContent = "No temperatures yet.";
  }
}

