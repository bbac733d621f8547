// Dashboard: every printer card, live through /ws/printers/, with its buttons.
import { api, clearError, liveFeed, showError, showJob, showState, tempsText } from "./api.js";
import { answerPrompt, showPrompt } from "./prompt.js";

const cards = new Map();
for (const card of document.querySelectorAll("[data-test=printer-card]")) {
  cards.set(card.dataset.printer, card);
}
const lastIds = {};

function setState(card, state, status) {
  card.dataset.state = state;
  const operator = Boolean(card.querySelector("[data-test=estop]:not([disabled])"));
  showPrompt(card.querySelector("[data-test=prompt]"), status?.prompt, operator);
  showState(card.querySelector("[data-test=state]"), state);
  const bedClear = card.querySelector("[data-test=bed-clear]");
  if (bedClear) bedClear.hidden = state !== "waitstart";
}

function onMessage(message) {
  if (message.type === "error") {
    showError(message.message);
    return;
  }
  const card = cards.get(message.printer);
  if (!card) return;
  switch (message.type) {
    case "hello":
      lastIds[message.printer] = message.last;
      setState(card, message.state, message.machine_status);
      card.querySelector("[data-test=temps]").textContent = tempsText(message.temperatures);
      showJob(card, message.job);
      break;
    case "state":
      setState(card, message.state, message.machine_status);
      break;
    case "temperatures":
      card.querySelector("[data-test=temps]").textContent = tempsText(message.temperatures);
      break;
    case "job":
      showJob(card, message.job);
      break;
    case "lines":
      lastIds[message.printer] = message.lines[message.lines.length - 1].id;
      break;
    default:
      break;
  }
}

if (cards.size) {
  // The dashboard shows no log lines: hide every kind but the non-maskable one.
  const params = () => {
    const query = new URLSearchParams({ filter: "7" });
    for (const [slug, id] of Object.entries(lastIds)) query.set(`last.${slug}`, id);
    return query.toString();
  };
  liveFeed("/ws/printers/", params, onMessage);
}

document.addEventListener("click", async (event) => {
  const button = event.target.closest("button[data-test]");
  const card = button?.closest("[data-test=printer-card]");
  if (!card) return;
  const slug = encodeURIComponent(card.dataset.printer);
  const test = button.dataset.test;
  if (test === "prompt-choice") {
    clearError();
    await answerPrompt(slug, button);
    return;
  }
  if (test !== "estop" && test !== "bed-clear") return;
  clearError();
  button.disabled = true;
  const path = test === "estop" ? "emergency" : "bedclear";
  const done = await api("POST", `/printer/${path}/${slug}`);
  button.disabled = false;
  if (done && test === "bed-clear") button.hidden = true;
});

// Worker hosts: the heartbeat's age counts up here; past the stale limit the host
// shows offline (a dead host writes no more heartbeats).
function tickHosts() {
  for (const host of document.querySelectorAll("[data-test=host]")) {
    if (!host.dataset.seen) continue;
    const age = Math.max(0, (Date.now() - Date.parse(host.dataset.seen)) / 1000);
    host.querySelector("[data-test=host-age]").textContent = `heartbeat ${Math.round(age)} s ago`;
    const online = age < Number(host.dataset.stale);
    const badge = host.querySelector("[data-test=host-state]");
    badge.dataset.state = online ? "idle" : "offline";
    badge.textContent = online ? "online" : "offline";
  }
}
tickHosts();
setInterval(tickHosts, 1000);
