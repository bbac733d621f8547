// Account page: create (shown once), list and revoke API keys; decide app-key requests.
import { api, clearError, showError } from "./api.js";

const $ = (test) => document.querySelector(`[data-test=${test}]`);
const when = (iso) => (iso ? iso.slice(0, 16).replace("T", " ") : "");

function keyRow(key) {
  const tr = document.createElement("tr");
  tr.dataset.test = "key";
  tr.dataset.key = key.id;
  const cells = [key.name, `ph_${key.prefix}…`, key.printer || "all", key.role || "mine", when(key.created), when(key.last_used) || "never", when(key.revoked) || "—"];
  for (const text of cells) {
    const td = document.createElement("td");
    td.textContent = text;
    tr.append(td);
  }
  const td = document.createElement("td");
  if (!key.revoked) {
    const b = document.createElement("button");
    b.type = "button";
    b.dataset.test = "key-revoke";
    b.className = "danger";
    b.textContent = "Revoke";
    td.append(b);
  }
  tr.append(td);
  return tr;
}

async function reloadKeys() {
  const keys = await api("GET", "/api/keys");
  if (keys) $("keys").tBodies[0].replaceChildren(...keys.sort((a, b) => b.id - a.id).map(keyRow));
}

$("key-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  clearError();
  const name = $("key-name").value.trim();
  if (!name) {
    showError("give the key a name (what it is for)");
    return;
  }
  const printer = $("key-printer").value || null;
  const key = await api("POST", "/api/keys", { name, printer });
  if (!key) return;
  $("new-key").textContent = key.key;
  $("new-key").closest(".newkey").hidden = false;
  $("key-name").value = "";
  await reloadKeys();
});

$("copy-key").addEventListener("click", async () => {
  try {
    await navigator.clipboard.writeText($("new-key").textContent);
    $("copy-key").textContent = "Copied";
  } catch {
    const range = document.createRange();
    range.selectNodeContents($("new-key"));
    getSelection().removeAllRanges();
    getSelection().addRange(range);
    showError("copying is not allowed here: the key is selected, copy it by hand");
  }
});

$("keys").addEventListener("click", async (event) => {
  const b = event.target.closest("[data-test=key-revoke]");
  if (!b || !confirm("Revoke this key? Programs using it stop working.")) return;
  clearError();
  b.disabled = true;
  await api("DELETE", `/api/keys/${b.closest("tr").dataset.key}`);
  await reloadKeys();
});

/** A select of the printers the key may be bound to (the new-key form's list). */
function printerChoice(fixed) {
  const select = document.createElement("select");
  select.dataset.test = "appkey-printer";
  select.setAttribute("aria-label", "Printer the key works for");
  for (const option of $("key-printer").options) select.append(option.cloneNode(true));
  if (fixed) {
    select.value = fixed;
    if (select.value !== fixed) {
      const option = document.createElement("option");
      option.value = option.textContent = fixed;
      select.append(option);
      select.value = fixed;
    }
    select.disabled = true;
  }
  return select;
}

function roleChoice() {
  const select = document.createElement("select");
  select.dataset.test = "appkey-role";
  select.setAttribute("aria-label", "What the key may do");
  for (const [value, label] of [["viewer", "viewer (watch)"], ["operator", "operator (print)"], ["admin", "admin"]]) {
    const option = document.createElement("option");
    option.value = value;
    option.textContent = label;
    select.append(option);
  }
  select.value = "operator";
  return select;
}

async function reloadApps() {
  const rows = await api("GET", "/api/appkeys/pending");
  if (!rows) return;
  const list = $("appkeys");
  // Keep the choices of a request the user is deciding on while the list refreshes.
  const kept = new Map([...list.querySelectorAll("[data-test=appkey]")].map((li) => [li.dataset.token, li]));
  const items = rows.map((row) => {
    if (kept.has(row.user_token)) return kept.get(row.user_token);
    const li = document.createElement("li");
    li.dataset.test = "appkey";
    li.dataset.token = row.user_token;
    const text = document.createElement("span");
    text.className = "name";
    text.dataset.test = "appkey-from";
    const asker = row.user ? ` for ${row.user}` : "";
    text.textContent = `${row.app} from ${row.origin || "an unknown address"}${asker}, until ${when(row.expires)}`;
    const approve = document.createElement("button");
    approve.type = "button";
    approve.dataset.test = "appkey-approve";
    approve.className = "primary";
    approve.textContent = "Approve";
    const deny = document.createElement("button");
    deny.type = "button";
    deny.dataset.test = "appkey-deny";
    deny.className = "danger";
    deny.textContent = "Deny";
    li.append(text, printerChoice(row.printer), roleChoice(), approve, deny);
    return li;
  });
  if (!items.length) {
    const li = document.createElement("li");
    li.className = "muted empty";
    li.textContent = "None waiting.";
    items.push(li);
  }
  list.replaceChildren(...items);
}

$("appkeys").addEventListener("click", async (event) => {
  const b = event.target.closest("button[data-test]");
  if (!b) return;
  clearError();
  const li = b.closest("li");
  const token = encodeURIComponent(li.dataset.token);
  const decision = b.dataset.test === "appkey-approve";
  const body = { decision };
  if (decision) {
    body.printer = li.querySelector("[data-test=appkey-printer]").value || null;
    body.role = li.querySelector("[data-test=appkey-role]").value;
  }
  b.disabled = true;
  const done = (await api("POST", `/plugin/appkeys/decision/${token}`, body)) !== undefined;
  b.disabled = false;
  if (done) {
    li.remove();
    await reloadKeys();
  }
  await reloadApps();
});

reloadApps();
setInterval(reloadApps, 5000);
