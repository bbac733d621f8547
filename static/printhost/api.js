// What every page shares: calling the JSON API, showing its errors, the live feed.

const errorBox = document.querySelector("[data-test=error]");

/** Show a failed action's message in the page's error area. */
export function showError(message) {
  if (!errorBox) return;
  errorBox.querySelector(".error-text").textContent = message;
  errorBox.hidden = false;
}

export function clearError() {
  if (errorBox) errorBox.hidden = true;
}

errorBox?.querySelector(".dismiss")?.addEventListener("click", clearError);

export function csrfToken() {
  const meta = document.querySelector("meta[name=csrf-token]");
  if (meta && meta.content) return meta.content;
  const cookie = document.cookie.split("; ").find((c) => c.startsWith("csrftoken="));
  return cookie ? decodeURIComponent(cookie.split("=")[1]) : "";
}

/** The API's error text of a failed response, or a plain one for the status. */
export function errorOf(status, body) {
  if (body && typeof body === "object" && body.error) return body.error;
  if (status === 0) return "the server did not answer";
  return `the server answered ${status}`;
}

/**
 * Call the API; resolves with `data` of the `{error, data}` envelope. On failure the
 * message goes to the error area and the promise resolves with `undefined`, so a
 * click handler never leaves an unhandled rejection behind. Success leaves the
 * error area alone: each user action clears it when it starts.
 */
export async function api(method, url, body) {
  const options = { method, credentials: "same-origin", headers: { Accept: "application/json" } };
  if (method !== "GET") options.headers["X-CSRFToken"] = csrfToken();
  if (body !== undefined) {
    options.headers["Content-Type"] = "application/json";
    options.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(url, options);
  } catch {
    showError("the server did not answer");
    return undefined;
  }
  let payload = null;
  if (response.status !== 204) {
    try {
      payload = await response.json();
    } catch {
      payload = null;
    }
  }
  if (!response.ok || (payload && payload.error)) {
    showError(errorOf(response.status, payload));
    return undefined;
  }
  return payload && "data" in payload ? payload.data : payload ?? {};
}

/** Human words for printer states (the model's labels). */
export const STATE_LABELS = {
  offline: "offline",
  connecting: "connecting",
  idle: "idle",
  printing: "printing",
  paused: "paused",
  waitstart: "waiting for the bed to be cleared",
  error: "error",
};

/** Seconds as m:ss or h:mm:ss; a dash when unknown. */
export function clock(seconds) {
  if (seconds === null || seconds === undefined) return "—";
  const total = Math.max(0, Math.floor(seconds));
  const h = Math.floor(total / 3600);
  const m = Math.floor((total % 3600) / 60);
  const s = String(total % 60).padStart(2, "0");
  return h ? `${h}:${String(m).padStart(2, "0")}:${s}` : `${m}:${s}`;
}

/** `T0 205/210 °C · B 60/60 °C` */
export function tempsText(temperatures) {
  const parts = [];
  for (const [name, r] of Object.entries(temperatures || {})) {
    if (!r || typeof r !== "object") continue;
    const now = r.current == null ? "—" : Math.round(r.current);
    const goal = r.target == null ? "—" : Math.round(r.target);
    parts.push(`${name} ${now}/${goal} °C`);
  }
  return parts.join(" · ") || "—";
}

/** Fill the job fields (name, state, progress, times) inside *root*. */
export function showJob(root, job) {
  const set = (name, text) => {
    const el = root.querySelector(`[data-test=${name}]`);
    if (el) el.textContent = text;
  };
  set("job-name", job ? job.name : "No job");
  set("job-state", job ? job.state : "");
  set("elapsed", clock(job ? job.elapsed : null));
  set("remaining", clock(job ? job.eta : null));
  const ends = job?.ends_at ? new Date(job.ends_at) : null;
  set("ends-at", ends ? ends.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" }) : "—");
  set("layer", job?.layer ? `${job.layer} / ${job.layers}` : "—");
  set("filament", job?.filament_used != null ? `${(job.filament_used / 1000).toFixed(2)} m` : "—");
  const bar = root.querySelector("[data-test=progress]");
  if (bar) bar.value = job ? (job.time_progress ?? job.progress) : 0;
  const picture = root.querySelector("[data-test=thumbnail]");
  if (picture) {
    const src = pickThumbnail(job, 96);
    if (src && picture.getAttribute("src") !== src) picture.src = src;
    picture.hidden = !src;
  }
}

/** The smallest thumbnail at least `smallest` px wide (else the largest), or "". */
export function pickThumbnail(job, smallest) {
  const pictures = job?.analysis?.thumbnails || [];
  if (!pictures.length) return "";
  const wide = pictures.filter((p) => p.width >= smallest).sort((a, b) => a.width - b.width);
  return (wide[0] || pictures[0]).url;
}

/** A job's analysis in a few words for a queue row. */
export function analysisText(job) {
  const analysis = job.analysis;
  if (!analysis) return "";
  if (analysis.state === "failed") return "analysis failed";
  if (analysis.state !== "done") return "analysing…";
  const parts = [`≈ ${clock(analysis.estimated_seconds)}`];
  if (analysis.filament_total) parts.push(`${(analysis.filament_total / 1000).toFixed(2)} m`);
  if (analysis.layers) parts.push(`${analysis.layers} layers`);
  return parts.join(" · ");
}

/** Show a printer state in a badge. */
export function showState(badge, state) {
  if (!badge) return;
  badge.textContent = STATE_LABELS[state] || state;
  badge.dataset.state = state;
}

/**
 * A websocket to the live feed that reconnects with backoff and resumes after the
 * last line id seen (`params()` gives the query string at each connect).
 */
export function liveFeed(path, params, onMessage) {
  let socket = null;
  let delay = 500;
  const open = () => {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    socket = new WebSocket(`${scheme}://${location.host}${path}?${params()}`);
    socket.addEventListener("open", () => { delay = 500; });
    socket.addEventListener("message", (event) => {
      let message;
      try {
        message = JSON.parse(event.data);
      } catch {
        return;
      }
      onMessage(message);
    });
    socket.addEventListener("close", (event) => {
      if ([4401, 4403, 4404].includes(event.code)) {
        showError("the live feed was refused: reload the page or log in again");
        return;
      }
      setTimeout(open, delay);
      delay = Math.min(delay * 2, 10000);
    });
  };
  open();
  return {
    send(message) {
      if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
    },
  };
}
