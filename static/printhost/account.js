// Account page: create (shown once), list and revoke API keys; decide app-key requests.
import { api, clearError, showError } from "./api.js";

const $ = (test) => document.querySelector(`[data-test=${test}]`);
const when = (iso) => (iso ? iso.slice(0, 16).replace("T", " ") : "");

function keyRow(key) {
  const tr = document.createElement("tr");
  tr.dataset.test = "key";
  tr.dataset.key = key.id;
  const cells = [key.name, `ph_${key.prefix}…`, key.printer || "all", when(key.created), when(key.last_used) || "never", when(key.revoked) || "—"];
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

async function reloadApps() {
  const rows = await api("GET", "/api/appkeys/pending");
  if (!rows) return;
  const items = rows.map((row) => {
    const li = document.createElement("li");
    li.dataset.test = "appkey";
    li.dataset.token = row.user_token;
    const text = document.createElement("span");
    text.className = "name";
    text.textContent = `${row.app} from ${row.origin || "unknown"}${row.user ? ` for ${row.user}` : ""}`;
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
    li.append(text, approve, deny);
    return li;
  });
  if (!items.length) {
    const li = document.createElement("li");
    li.className = "muted empty";
    li.textContent = "None waiting.";
    items.push(li);
  }
  $("appkeys").replaceChildren(...items);
}

$("appkeys").addEventListener("click", async (event) => {
  const b = event.target.closest("button[data-test]");
  if (!b) return;
  const token = encodeURIComponent(b.closest("li").dataset.token);
  const decision = b.dataset.test === "appkey-approve";
  b.disabled = true;
  if ((await api("POST", `/plugin/appkeys/decision/${token}`, { decision })) !== undefined) {
    await reloadKeys();
  }
  await reloadApps();
});

reloadApps();
setInterval(reloadApps, 5000);
