// The history page: more runs on demand, and running runs kept live (the API's
// /printer/history with the page's filters). The first render is the server's.

import { api, clock } from "./api.js";

const section = document.querySelector("[data-test=history]");
const list = section.querySelector("[data-test=runs]");
const more = section.querySelector("[data-test=more-runs]");
const counter = section.querySelector("[data-test=runs-count]");
const query = section.dataset.query;

/** While a run prints its figures move: poll often; otherwise now and then. */
const LIVE_MS = 5000;
const IDLE_MS = 60000;
const PAGE = 50;

const OUTCOMES = {
  completed: "completed",
  aborted: "aborted",
  failed: "failed",
  interrupted: "interrupted",
  in_progress: "in progress",
};

function pad(n) {
  return String(n).padStart(2, "0");
}

function localTime(iso, withDate) {
  const t = new Date(iso);
  const time = `${pad(t.getHours())}:${pad(t.getMinutes())}`;
  if (!withDate) return time;
  return `${t.getFullYear()}-${pad(t.getMonth() + 1)}-${pad(t.getDate())} ${time}`;
}

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs)) node.setAttribute(name, value);
  for (const child of children) node.append(child);
  return node;
}

function jobLink(number, exists, text) {
  return exists ? el("a", { href: `/jobs/${number}/` }, text) : document.createTextNode(text);
}

function fact(name, value, test) {
  const dd = el("dd", test ? { "data-test": test } : {});
  dd.append(value);
  return el("div", {}, el("dt", {}, name), dd);
}

/** One run as a card: the same markup as templates/history.html. */
export function runCard(run) {
  const card = el("li", {
    class: "panel run",
    "data-test": "run",
    "data-job": String(run.job),
    "data-outcome": run.outcome,
  });
  const badge = el("span", { class: "badge", "data-state": run.outcome }, OUTCOMES[run.outcome] || run.outcome);
  card.append(el("div", { class: "card-head" }, el("h3", {}, jobLink(run.job, run.job_exists, run.name)), badge));
  const started = el("time", { datetime: run.started }, localTime(run.started, true));
  const when = el("span", {}, started, run.finished ? ` → ${localTime(run.finished, false)}` : "");
  const filament = run.filament_used == null ? "—" : `${(run.filament_used / 1000).toFixed(2)} m`;
  card.append(
    el(
      "dl",
      { class: "facts" },
      fact("Job", `#${run.job}`),
      fact("Printer", run.printer_name || run.printer),
      fact("By", run.user || "—"),
      fact("Started", when),
      fact("Time", clock(run.print_seconds), "run-time"),
      fact("Filament", filament, "run-filament"),
      fact("Layers", run.layers ? `${run.layer} / ${run.layers}` : "—", "run-layers"),
    ),
  );
  if (run.origin) card.append(el("p", { class: "muted origin" }, `from ${run.origin}`));
  if (run.resumed_from) {
    const from = run.resumed_from;
    card.append(
      el("p", { "data-test": "run-resumed" }, `Resumed from line ${from.line} of `, jobLink(from.job, from.exists, `#${from.job}`)),
    );
  }
  if (run.resumed_by.length) {
    const by = el("p", { "data-test": "run-resumed-by" }, "Resumed by ");
    run.resumed_by.forEach((r, i) => by.append(i ? ", " : "", jobLink(r.job, r.exists, `#${r.job}`)));
    card.append(by);
  }
  if (run.message) card.append(el("p", { class: "message", "data-test": "run-message" }, run.message));
  return card;
}

function url(offset, limit) {
  const params = new URLSearchParams(query);
  params.set("offset", String(offset));
  params.set("limit", String(limit));
  return `/printer/history?${params}`;
}

function show(data, replace) {
  if (replace) list.replaceChildren();
  list.querySelector("[data-test=no-runs]")?.remove();
  for (const run of data.runs) list.append(runCard(run));
  if (!list.children.length) list.append(el("li", { class: "muted empty", "data-test": "no-runs" }, "No runs match."));
  counter.textContent = `(${data.count})`;
  more.hidden = list.querySelectorAll("[data-test=run]").length >= data.count;
}

more.addEventListener("click", async () => {
  const shown = list.querySelectorAll("[data-test=run]").length;
  const data = await api("GET", url(shown, PAGE));
  if (data) show(data, false);
});

async function refresh() {
  const shown = Math.min(1000, Math.max(PAGE, list.querySelectorAll("[data-test=run]").length));
  const data = await api("GET", url(0, shown));
  if (data) show(data, true);
  schedule();
}

function schedule() {
  const live = list.querySelector("[data-outcome=in_progress]") !== null;
  setTimeout(refresh, live ? LIVE_MS : IDLE_MS);
}

schedule();
