// Farm page: cancel and reorder farm jobs, set what a printer has loaded, and keep the
// page's live parts fresh (the server renders them; this fetches the page again).
import { api, clearError } from "./api.js";

const REFRESH_MS = 4000;

/** Replace each [data-live] part with the server's newer one, unless the user is
 * typing in it or has a form open there. */
async function refresh() {
  let text;
  try {
    const response = await fetch(location.pathname, { credentials: "same-origin" });
    if (!response.ok) return;
    text = await response.text();
  } catch {
    return;
  }
  const fresh = new DOMParser().parseFromString(text, "text/html");
  for (const part of document.querySelectorAll("[data-live]")) {
    const busy = part.contains(document.activeElement) || part.querySelector("details[open]");
    const newer = fresh.querySelector(`[data-live="${part.dataset.live}"]`);
    if (!busy && newer) part.replaceWith(document.importNode(newer, true));
  }
}

document.addEventListener("click", async (event) => {
  const button = event.target.closest("button[data-test]");
  const item = button?.closest("[data-test=farm-job]");
  if (!item) return;
  const test = button.dataset.test;
  const url = `/printer/farm/${encodeURIComponent(item.dataset.id)}`;
  clearError();
  button.disabled = true;
  let done;
  if (test === "farm-cancel") {
    if (!confirm("Take this job out of the farm queue? Its file is removed.")) {
      button.disabled = false;
      return;
    }
    done = await api("POST", `${url}/cancel`);
  } else if (test === "farm-sooner" || test === "farm-later") {
    done = await api("PATCH", url, { priority: Number(button.dataset.priority) });
  }
  button.disabled = false;
  if (done) await refresh();
});

document.addEventListener("submit", async (event) => {
  const form = event.target.closest("[data-test=loaded-form]");
  if (!form) return;
  event.preventDefault();
  clearError();
  const fields = Object.fromEntries(new FormData(form));
  const saved = await api("POST", `/printer/loaded/${encodeURIComponent(form.dataset.printer)}`, fields);
  if (!saved) return;
  form.closest("details").open = false;
  document.activeElement?.blur();
  await refresh();
});

setInterval(refresh, REFRESH_MS);
