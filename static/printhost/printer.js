// The printer page: live state, terminal, queue and upload, chart, controls, connection.
import {
  analysisText, api, clearError, csrfToken, errorOf, liveFeed, pickThumbnail, showError, showJob, showState, tempsText,
} from "./api.js";
import { TempChart } from "./chart.js";
import { answerPrompt, showPrompt } from "./prompt.js";
import { sdCardPanel } from "./sdcard.js";
import { toolpathPreview } from "./toolpath.js";

const root = document.getElementById("printer");
const slug = root.dataset.printer;
const base = encodeURIComponent(slug);
const operator = root.dataset.operator === "1";
const grbl = root.dataset.firmware === "grbl";
const $ = (test, scope = root) => scope.querySelector(`[data-test=${test}]`);
let lastId = Number(root.dataset.last) || 0;
let currentJob = null;

// -- state and job -------------------------------------------------------------------

function setState(state, message) {
  showState($("state"), state);
  if (message !== undefined) $("state-message").textContent = message;
  const bedClear = $("bed-clear");
  if (bedClear) bedClear.hidden = state !== "waitstart";
}

const preview = toolpathPreview($("preview"));

function setJob(job) {
  const active = job && (job.state === "printing" || job.state === "paused");
  currentJob = active ? job : null;
  showJob($("job"), job);
  if (active && job.kind === "print") preview.show(slug, job.id).then((shown) => shown && preview.follow(job));
  else preview.stop();
  if ($("pause")) {
    $("pause").hidden = !(active && job.state === "printing");
    $("resume").hidden = !(active && job.state === "paused");
    $("abort").hidden = !active;
  }
}

// -- terminal ------------------------------------------------------------------------

const terminal = $("terminal");
const MAX_LINES = 2000;
let follow = true;
terminal.addEventListener("scroll", () => {
  follow = terminal.scrollTop + terminal.clientHeight >= terminal.scrollHeight - 8;
});

function appendLine(attrs, text) {
  const div = document.createElement("div");
  for (const [name, value] of Object.entries(attrs)) div.setAttribute(name, value);
  div.textContent = text;
  terminal.append(div);
  while (terminal.childElementCount > MAX_LINES) terminal.firstElementChild.remove();
}

function addLines(lines) {
  for (const line of lines) {
    if (line.id <= lastId && terminal.querySelector(`[data-id="${line.id}"]`)) continue;
    appendLine({ "data-test": "line", "data-id": line.id, "data-type": line.type }, line.text);
    lastId = Math.max(lastId, line.id);
  }
  if (follow) terminal.scrollTop = terminal.scrollHeight;
}
terminal.scrollTop = terminal.scrollHeight;

for (const bit of [1, 2, 4, 8]) {
  $(`filter-${bit}`).addEventListener("change", (event) => {
    terminal.classList.toggle(`hide-${bit}`, !event.target.checked);
    if (follow) terminal.scrollTop = terminal.scrollHeight;
  });
}

async function send(command) {
  const data = await api("POST", `/printer/send/${base}?cmd=${encodeURIComponent(command)}`);
  if (data && command.toUpperCase().startsWith("[ESP")) {
    const reply = data.reply || `(${data.state || "no reply"})`;
    appendLine({ "data-test": "reply", "data-type": "8" }, `${command} → ${reply}`);
    if (follow) terminal.scrollTop = terminal.scrollHeight;
  }
  return data;
}

const history = [];
let historyAt = 0;
const input = $("command");
$("send-form")?.addEventListener("submit", async (event) => {
  event.preventDefault();
  clearError();
  const command = input.value.trim();
  if (!command) {
    showError("type a command first");
    return;
  }
  if (history[history.length - 1] !== command) history.push(command);
  historyAt = history.length;
  input.value = "";
  follow = true;
  await send(command);
});
input?.addEventListener("keydown", (event) => {
  if (event.key !== "ArrowUp" && event.key !== "ArrowDown") return;
  event.preventDefault();
  historyAt += event.key === "ArrowUp" ? -1 : 1;
  historyAt = Math.max(0, Math.min(history.length, historyAt));
  input.value = history[historyAt] ?? "";
});

// -- queue ---------------------------------------------------------------------------

const list = $("queue-list");
const FINISHED = ["completed", "aborted", "failed", "interrupted"];
let jobs = JSON.parse(document.getElementById("jobs-data").textContent);

function button(test, label, extra = "") {
  const b = document.createElement("button");
  b.type = "button";
  b.dataset.test = test;
  b.textContent = label;
  if (extra) b.className = extra;
  return b;
}

function renderQueue() {
  const rows = jobs.map((job) => {
    const li = document.createElement("li");
    li.dataset.test = "queue-job";
    li.dataset.job = job.id;
    li.dataset.state = job.state;
    const link = document.createElement("a");
    link.href = `/jobs/${job.id}/`;
    link.className = "name";
    link.textContent = job.name;
    const state = document.createElement("span");
    state.className = "muted";
    state.dataset.test = "queue-job-state";
    const percent = job.time_progress ?? job.progress;
    state.textContent = job.state === "printing" ? `printing ${percent.toFixed(1)} %` : job.state;
    const src = pickThumbnail(job, 48);
    if (src) {
      const picture = document.createElement("img");
      picture.className = "thumb small";
      picture.dataset.test = "queue-job-thumbnail";
      picture.src = src;
      picture.alt = "";
      picture.width = picture.height = 44;
      picture.loading = "lazy";
      li.append(picture);
    }
    li.append(link, state);
    const figures = analysisText(job);
    if (figures) {
      const facts = document.createElement("span");
      facts.className = "muted";
      facts.dataset.test = "queue-job-analysis";
      facts.textContent = figures;
      li.append(facts);
    }
    if (job.kind && job.kind !== "print") {
      const kind = document.createElement("span");
      kind.className = "badge";
      kind.dataset.test = "queue-job-kind";
      kind.textContent = job.kind === "sd_print" ? "from SD card" : `copy to SD card as ${job.sd_name}`;
      li.append(kind);
    }
    if (operator) {
      const actions = document.createElement("span");
      actions.className = "actions";
      if (job.state === "queued") {
        li.draggable = true;
        actions.append(button("job-up", "↑"), button("job-down", "↓"));
        actions.firstChild.setAttribute("aria-label", `Move ${job.name} up`);
        actions.lastChild.setAttribute("aria-label", `Move ${job.name} down`);
      }
      if (job.state === "stored") actions.append(button("job-start", "Start", "primary"));
      if (FINISHED.includes(job.state)) actions.append(button("job-reprint", "Reprint"));
      const copyable = job.kind === "print" && (job.state === "stored" || FINISHED.includes(job.state));
      if (!grbl && copyable) actions.append(button("job-sd-copy", "Copy to SD"));
      if (job.state !== "printing" && job.state !== "paused") actions.append(button("job-delete", "Delete", "danger"));
      li.append(actions);
    }
    return li;
  });
  if (!rows.length) {
    const empty = document.createElement("li");
    empty.className = "muted empty";
    empty.textContent = "No jobs.";
    rows.push(empty);
  }
  list.replaceChildren(...rows);
}

async function reloadQueue() {
  // Open jobs in queue order, then the newest finished: as many as the page shows.
  const data = await api("GET", `/printer/job/${base}?a=list&finished=${list.dataset.finished}`);
  if (data) {
    jobs = data;
    renderQueue();
  }
}

async function reorder(order) {
  const data = await api("POST", `/printer/queue/${base}`, { order });
  await reloadQueue();
  return data;
}

function queuedIds() {
  return jobs.filter((j) => j.state === "queued").map((j) => j.id);
}

list.addEventListener("click", async (event) => {
  const b = event.target.closest("button[data-test]");
  if (!b) return;
  const id = Number(b.closest("[data-test=queue-job]").dataset.job);
  clearError();
  b.disabled = true;
  const test = b.dataset.test;
  if (test === "job-up" || test === "job-down") {
    const ids = queuedIds();
    const at = ids.indexOf(id);
    const to = at + (test === "job-up" ? -1 : 1);
    if (to >= 0 && to < ids.length) {
      [ids[at], ids[to]] = [ids[to], ids[at]];
      await reorder(ids);
    }
  } else if (test === "job-sd-copy") {
    const print = confirm("Print it from the SD card once it is copied? (Cancel: only copy it)");
    await api("POST", `/printer/sd/${base}/upload`, { job: id, print });
    await reloadQueue();
  } else {
    const action = { "job-start": "start", "job-reprint": "reprint", "job-delete": "delete" }[test];
    if (action === "delete" && !confirm("Delete this job and its file?")) {
      b.disabled = false;
      return;
    }
    await api("POST", `/printer/job/${base}?a=${action}&id=${id}`);
    await reloadQueue();
  }
  b.disabled = false;
});

let dragged = null;
list.addEventListener("dragstart", (event) => {
  dragged = event.target.closest("[data-test=queue-job]");
  dragged?.classList.add("dragging");
});
list.addEventListener("dragover", (event) => event.preventDefault());
list.addEventListener("drop", async (event) => {
  event.preventDefault();
  const target = event.target.closest("[data-test=queue-job]");
  dragged?.classList.remove("dragging");
  if (!dragged || !target || target === dragged || target.dataset.state !== "queued") return;
  const ids = queuedIds().filter((i) => i !== Number(dragged.dataset.job));
  ids.splice(ids.indexOf(Number(target.dataset.job)), 0, Number(dragged.dataset.job));
  dragged = null;
  await reorder(ids);
});

// -- upload --------------------------------------------------------------------------

function upload(file, bar) {
  return new Promise((resolve) => {
    const form = new FormData();
    form.append("filename", file, file.name);
    const xhr = new XMLHttpRequest();
    xhr.open("POST", `/printer/job/${base}?a=upload`);
    xhr.setRequestHeader("X-CSRFToken", csrfToken());
    xhr.responseType = "json";
    xhr.upload.addEventListener("progress", (event) => {
      if (event.lengthComputable) bar.value = (100 * event.loaded) / event.total;
    });
    xhr.addEventListener("load", () => {
      const body = xhr.response;
      if (xhr.status >= 200 && xhr.status < 300 && body && !body.error) resolve(body.data);
      else {
        showError(errorOf(xhr.status, body));
        resolve(undefined);
      }
    });
    xhr.addEventListener("error", () => {
      showError("the server did not answer");
      resolve(undefined);
    });
    xhr.send(form);
  });
}

$("upload-form")?.addEventListener("submit", async (event) => {
  event.preventDefault();
  clearError();
  const file = $("upload-file").files[0];
  const copies = Number($("upload-copies").value || 1);
  if (!file) {
    showError("choose a G-code file first");
    return;
  }
  if (!Number.isInteger(copies) || copies < 1 || copies > 100) {
    showError("copies must be a whole number from 1 to 100");
    return;
  }
  const bar = $("upload-progress");
  const submit = $("upload");
  bar.value = 0;
  bar.hidden = false;
  submit.disabled = true;
  const job = await upload(file, bar);
  if (job) {
    for (let i = 1; i < copies; i += 1) {
      if (!(await api("POST", `/printer/job/${base}?a=reprint&id=${job.id}`))) break;
    }
    $("upload-file").value = "";
  }
  bar.hidden = true;
  submit.disabled = false;
  await reloadQueue();
});

// -- controls and connection ---------------------------------------------------------

async function jog(axis, dir) {
  const step = root.querySelector("[data-test=jog-step]:checked")?.value || "10";
  const distance = `${dir === "-" ? "-" : ""}${step}`;
  if (grbl) {
    await send(`$J=G91 ${axis}${distance} F1000`);
  } else if (await send("G91")) {
    await send(`G0 ${axis}${distance} F${axis === "Z" ? 600 : 3000}`);
    await send("G90");
  }
}

async function setTemperature(test, code) {
  const field = $(test === "set-hotend" ? "hotend-target" : "bed-target");
  const value = Number(field.value);
  if (field.value === "" || !Number.isFinite(value) || value < 0 || value > Number(field.max)) {
    showError(`the temperature must be a number from 0 to ${field.max} °C`);
    return;
  }
  await send(`${code} S${Math.round(value)}`);
}

root.addEventListener("click", async (event) => {
  const b = event.target.closest("button[data-test]");
  if (!b || b.closest("[data-test=queue-list]")) return;
  clearError();
  const test = b.dataset.test;
  const posts = {
    estop: "emergency", "soft-reset": "emergency", "bed-clear": "bedclear",
    connect: "connect", disconnect: "disconnect",
  };
  const jobActions = { pause: "pause", resume: "resume", abort: "abort" };
  if (test === "abort" && !confirm("Abort the running job?")) return;
  if (posts[test]) {
    if (await api("POST", `/printer/${posts[test]}/${base}`)) {
      if (test === "bed-clear") b.hidden = true;
    }
  } else if (jobActions[test]) {
    await api("POST", `/printer/job/${base}?a=${jobActions[test]}`);
  } else if (test === "prompt-choice") {
    await answerPrompt(base, b);
  } else if (test === "jog") {
    await jog(b.dataset.axis, b.dataset.dir);
  } else if (test === "set-hotend") {
    await setTemperature(test, "M104");
  } else if (test === "set-bed") {
    await setTemperature(test, "M140");
  } else if (b.dataset.cmd) {
    await send(b.dataset.cmd);
  }
});

$("connection-form")?.addEventListener("submit", async (event) => {
  event.preventDefault();
  clearError();
  const port = $("port").value.trim();
  const baud = Number($("baud").value);
  if (!port || !Number.isInteger(baud) || baud <= 0) {
    showError("give a port and a whole-number baud rate");
    return;
  }
  await api("PATCH", `/printer/config/${base}`, { port, baud });
});

$("loaded-form")?.addEventListener("submit", async (event) => {
  event.preventDefault();
  clearError();
  const loaded = await api("POST", `/printer/loaded/${base}`, Object.fromEntries(new FormData(event.target)));
  if (!loaded) return;
  const words = [loaded.colour, loaded.material].filter(Boolean).join(" ");
  $("loaded-material").textContent = words || "nothing set";
  $("loaded-nozzle").textContent = loaded.nozzle_diameter ? `${loaded.nozzle_diameter} mm` : "—";
  $("loaded-by").textContent = `Set by ${loaded.loaded_by} just now`;
});

// -- chart and live feed -------------------------------------------------------------

const chart = new TempChart($("temp-chart"), 30);
async function loadHistory() {
  const samples = await api("GET", `/printer/temperatures/${base}?minutes=30`);
  for (const sample of samples || []) chart.add(sample.time, sample.temperatures);
  chart.draw();
}

const showCard = sdCardPanel($("sd-card"), base, operator, reloadQueue);

function onMessage(message) {
  if ("sd_card" in message) showCard(message.sd_card);
  switch (message.type) {
    case "hello":
      setState(message.state, message.message);
      showPrompt($("prompt"), message.machine_status?.prompt, operator);
      $("temps").textContent = tempsText(message.temperatures);
      setJob(message.job);
      break;
    case "lines":
      addLines(message.lines);
      break;
    case "state":
      setState(message.state, message.message);
      showPrompt($("prompt"), message.machine_status?.prompt, operator);
      if (message.state !== "printing" && message.state !== "paused") reloadQueue();
      break;
    case "temperatures":
      $("temps").textContent = tempsText(message.temperatures);
      chart.add(Date.now(), message.temperatures);
      chart.draw();
      break;
    case "job": {
      setJob(message.job);
      const known = jobs.find((j) => j.id === message.job.id);
      if (known && known.state === message.job.state) {
        Object.assign(known, message.job);
        renderQueue();
      } else {
        reloadQueue();
      }
      break;
    }
    case "truncated":
      appendLine(
        { "data-test": "reply", "data-type": "8" },
        message.paged ? "… older lines are in the log's history" : "… older lines were pruned from the log",
      );
      break;
    case "error":
      showError(message.message);
      break;
    default:
      break;
  }
}

renderQueue();
loadHistory();
setInterval(() => chart.draw(), 30000);
liveFeed(`/ws/printers/${base}/`, () => `last=${lastId}`, onMessage);
