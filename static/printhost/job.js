// The job page: the file's toolpath preview, following the print while it runs.
import { liveFeed } from "./api.js";
import { toolpathPreview } from "./toolpath.js";

const holder = document.getElementById("job-preview");
const slug = holder.dataset.printer;
const jobId = Number(holder.dataset.job);
const preview = toolpathPreview(holder.querySelector("[data-test=preview]"));
const running = (job) => job && job.id === jobId && (job.state === "printing" || job.state === "paused");

preview.show(slug, jobId).then((shown) => {
  if (!shown) return;
  liveFeed(`/ws/printers/${encodeURIComponent(slug)}/`, () => "", (message) => {
    if ((message.type === "hello" || message.type === "job") && message.job?.id === jobId) {
      if (running(message.job)) preview.follow(message.job);
      else preview.stop();
    }
  });
});
