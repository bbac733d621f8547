// The job page: the file's toolpath preview, following the print while it runs, and
// its objects, each of which an operator may cancel while the job prints.
import { api, liveFeed } from "./api.js";
import { toolpathPreview } from "./toolpath.js";

const holder = document.getElementById("job-preview");
const slug = holder.dataset.printer;
const jobId = Number(holder.dataset.job);
const preview = toolpathPreview(holder.querySelector("[data-test=preview]"));
const objectsPanel = document.querySelector("[data-test=objects]");
const running = (job) => job && job.id === jobId && (job.state === "printing" || job.state === "paused");
let ranges = null;

function showObjects(job) {
  if (!objectsPanel || !job?.objects) return;
  const live = running(job);
  for (const { name, cancelled } of job.objects) {
    const item = [...objectsPanel.querySelectorAll("[data-test=object]")].find((li) => li.dataset.name === name);
    if (!item) continue;
    item.dataset.cancelled = String(cancelled);
    item.querySelector("[data-test=object-cancelled]").hidden = !cancelled;
    item.querySelector("[data-test=cancel-object]").hidden = cancelled || !live;
  }
  const names = job.objects.filter((o) => o.cancelled).map((o) => o.name);
  if (ranges) preview.cancel(ranges, names);
}

objectsPanel?.addEventListener("click", async (event) => {
  const button = event.target.closest("[data-test=cancel-object]");
  if (!button) return;
  const name = button.closest("[data-test=object]").dataset.name;
  const question = `Stop printing "${name}"? Its extrusion stops from the next line sent; the other objects go on. This cannot be undone.`;
  if (!window.confirm(question)) return;
  button.disabled = true;
  const data = await api("POST", `/printer/objects/${encodeURIComponent(slug)}`, { id: jobId, object: name });
  button.disabled = false;
  if (data) showObjects({ id: jobId, state: data.state, objects: data.objects.map((o) => ({ name: o, cancelled: data.cancelled.includes(o) })) });
});

preview.show(slug, jobId).then(async (shown) => {
  if (!shown && !objectsPanel) return;
  if (objectsPanel) {
    const data = await api("GET", `/printer/objects/${encodeURIComponent(slug)}?id=${jobId}&ranges=1`);
    ranges = data?.ranges ?? null;
    if (data && ranges) preview.cancel(ranges, data.cancelled);
  }
  liveFeed(`/ws/printers/${encodeURIComponent(slug)}/`, () => "", (message) => {
    if ((message.type === "hello" || message.type === "job") && message.job?.id === jobId) {
      showObjects(message.job);
      if (!shown) return;
      if (running(message.job)) preview.follow(message.job);
      else preview.stop();
    }
  });
});
