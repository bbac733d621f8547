// The printer's own dialog (Marlin host prompt, e.g. M600 "Nozzle Parked"): shown
// with its buttons; a click answers it through POST /printer/prompt/<slug>.
import { api } from "./api.js";

/** Fill *box* (the [data-test=prompt] element) from machine_status.prompt. */
export function showPrompt(box, prompt, operator) {
  if (!box) return;
  box.hidden = !prompt;
  if (!prompt) return;
  box.querySelector("[data-test=prompt-message]").textContent = prompt.message;
  box.querySelector("[data-test=prompt-hint]").hidden = Boolean(prompt.answerable);
  const labels = prompt.choices.length ? prompt.choices : ["OK"];
  const buttons = labels.map((label, index) => {
    const b = document.createElement("button");
    b.type = "button";
    b.dataset.test = "prompt-choice";
    b.dataset.choice = index;
    b.textContent = label;
    if (index === 0) b.className = "primary";
    b.disabled = !operator;
    if (!operator) b.title = "operator role needed";
    return b;
  });
  box.querySelector("[data-test=prompt-choices]").replaceChildren(...buttons);
}

/** Send the choice of *button*; the dialog goes once the worker answered. */
export async function answerPrompt(slug, button) {
  button.disabled = true;
  const done = await api("POST", `/printer/prompt/${slug}`, { choice: Number(button.dataset.choice) });
  if (done) button.closest("[data-test=prompt]").hidden = true;
  else button.disabled = false;
  return done;
}
