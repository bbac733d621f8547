// The printer page's SD card panel: the card's files, print or delete one, list again.
import { api, clearError } from "./api.js";

function sizeText(bytes) {
  if (!Number.isFinite(bytes)) return "";
  if (bytes < 1024) return `${bytes} B`;
  if (bytes < 1024 * 1024) return `${(bytes / 1024).toFixed(1)} KB`;
  return `${(bytes / 1024 / 1024).toFixed(1)} MB`;
}

function statusText(card) {
  if (!card || card.present === undefined || card.present === null) {
    return "Not listed yet.";
  }
  if (!card.present) return card.message || "No SD card.";
  const at = card.listed ? new Date(card.listed).toLocaleTimeString() : "";
  const count = (card.files || []).length;
  return `${count} file${count === 1 ? "" : "s"}${at ? `, listed at ${at}` : ""}.`;
}

/**
 * Wire the panel (`[data-test=sd-card]`); returns `show(card)` for live updates.
 * *queued* runs after a print from the card was queued (the queue shows it).
 */
export function sdCardPanel(panel, base, operator, queued) {
  if (!panel) return () => {};
  const list = panel.querySelector("[data-test=sd-files]");
  const status = panel.querySelector("[data-test=sd-status]");

  function show(card) {
    status.textContent = statusText(card);
    const rows = ((card && card.files) || []).map((file) => {
      const li = document.createElement("li");
      li.dataset.test = "sd-file";
      li.dataset.name = file.name;
      const name = document.createElement("span");
      name.className = "name";
      name.textContent = file.long_name ? `${file.long_name} (${file.name})` : file.name;
      const size = document.createElement("span");
      size.className = "muted";
      size.textContent = sizeText(file.size);
      li.append(name, size);
      if (operator) {
        const actions = document.createElement("span");
        actions.className = "actions";
        for (const [test, label, css] of [["sd-print", "Print", "primary"], ["sd-delete", "Delete", "danger"]]) {
          const b = document.createElement("button");
          b.type = "button";
          b.dataset.test = test;
          b.className = css;
          b.textContent = label;
          b.setAttribute("aria-label", `${label} ${file.name}`);
          actions.append(b);
        }
        li.append(actions);
      }
      return li;
    });
    list.replaceChildren(...rows);
  }

  panel.addEventListener("click", async (event) => {
    const b = event.target.closest("button[data-test]");
    if (!b) return;
    clearError();
    const name = b.closest("[data-test=sd-file]")?.dataset.name;
    b.disabled = true;
    if (b.dataset.test === "sd-refresh") {
      await api("POST", `/printer/sd/${base}/refresh`);
    } else if (b.dataset.test === "sd-print") {
      if (await api("POST", `/printer/sd/${base}/print`, { name })) await queued();
    } else if (b.dataset.test === "sd-delete" && confirm(`Delete ${name} from the printer's SD card?`)) {
      await api("POST", `/printer/sd/${base}/delete`, { name });
    }
    b.disabled = false;
  });

  const data = panel.querySelector("#sd-data");
  show(data ? JSON.parse(data.textContent) : null);
  return show;
}
