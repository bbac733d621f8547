// The resume page: ask for a plan, wait for the worker that reads the file, show the
// preamble, start it once the operator has read it.
import { api, clearError } from "./api.js";

const root = document.querySelector("[data-resume]");
const printer = root.dataset.printer;
const job = Number(root.dataset.job);
const form = document.querySelector("[data-test=resume-form]");
const panel = document.querySelector("[data-test=resume-plan]");
const stateText = document.querySelector("[data-test=resume-plan-state]");
const warnings = document.querySelector("[data-test=resume-warnings]");
const preamble = document.querySelector("[data-test=resume-preamble]");
const start = document.querySelector("[data-test=resume-start]");
let planId = null;

function choice() {
  const from = form.querySelector("input[name=from]:checked").value;
  if (from === "layer") return { layer: Number(form.querySelector("[data-test=resume-layer]").value) };
  if (from === "line") return { line: Number(form.querySelector("[data-test=resume-line]").value) };
  return {};
}

function show(plan) {
  panel.hidden = false;
  const where = plan.layer === null ? `line ${plan.line}` : `layer ${plan.layer + 1} (line ${plan.line})`;
  const said = { pending: "reading the file…", ready: "ready", failed: `failed: ${plan.reason}`, started: "started" };
  stateText.textContent = `Resume at ${where}: ${said[plan.state] || plan.state}`;
  warnings.replaceChildren(
    ...(plan.machine.warnings || []).map((text) => Object.assign(document.createElement("li"), { textContent: text })),
  );
  preamble.textContent = plan.preamble.join("\n");
  if (start) start.hidden = plan.state !== "ready";
}

async function follow(id) {
  for (let wait = 250; ; wait = Math.min(wait * 2, 2000)) {
    const plan = await api("GET", `/printer/resume/${printer}?plan=${id}`);
    if (!plan || id !== planId) return;
    show(plan);
    if (plan.state !== "pending") return;
    await new Promise((done) => setTimeout(done, wait));
  }
}

form.addEventListener("submit", async (event) => {
  event.preventDefault();
  clearError();
  const plan = await api("POST", `/printer/resume/${printer}`, { id: job, ...choice() });
  if (!plan) return;
  planId = plan.id;
  show(plan);
  follow(plan.id);
});

start?.addEventListener("click", async () => {
  clearError();
  if (!window.confirm("Start the resume? The printer heats, homes X and Y and prints on the part on its bed.")) return;
  const resumed = await api("POST", `/printer/resume/${printer}/start`, { plan: planId });
  if (resumed) window.location.assign(`/jobs/${resumed.id}/`);
});
