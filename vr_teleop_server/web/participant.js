// The participant's page (/participant#token=...): the questionnaires due now, one block of items per screen, large
// touch targets; Next only once every item on the screen has an answer or "prefer not to answer"; nothing is sent
// before the last screen. The token (a participant role's, from /study/participants/add) admits only this.
import {connect} from "/rosbridge.js";
import * as names from "/names.js";

const PREFER_NOT = "prefer_not_to_answer";
const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.hash.slice(1)).get("token");
const scheme = location.protocol === "https:" ? "wss" : "ws";
const ros = connect(`${scheme}://${location.host}/`, {token, idPrefix: "participant"});

let due = [];          // what the server says is due, in order
let answered = 0;      // questionnaires this participant gave so far
let sheet = null;      // the questionnaire being filled in
let screen = 0;        // its block shown
let answers = {};      // item id -> number or PREFER_NOT

const UNKNOWN = "This page's link is not known to the server (or the participant withdrew): ask the experimenter " +
  "for the link again.";
// a reconnection keeps the screen and its answers: only a page with nothing on it asks what is due
ros.onopen = () => { $("connection").textContent = "connected"; $("connection").className = "badge on"; if (!sheet) load(); };
ros.onstatus = (m) => { if (m.level === "error" && /token/.test(m.msg)) say(UNKNOWN, true); };
ros.onclose = () => { $("connection").textContent = "reconnecting…"; $("connection").className = "badge off"; };

function say(text, bad = false) {
  $("message").textContent = text;
  $("message").className = bad ? "refused" : "";
}

async function load() {
  try {
    const r = await ros.callService(names.STUDY_QUESTIONNAIRE_DUE_SERVICE, {});
    due = JSON.parse(r.due_json);
    answered = r.answered;
    $("title").textContent = `Questionnaire · ${r.participant}`;
  } catch (err) {
    say(/authenticate|token/.test(err.message) ? UNKNOWN : err.message, true);
    return;
  }
  if (due.length === 0) {
    sheet = null;
    $("progress").textContent = answered ? `${answered} done` : "";
    $("block-title").textContent = "Nothing to fill in now. Thank you!";
    $("scale-note").textContent = "Please hand the tablet back.";
    $("items").replaceChildren();
    $("next").hidden = true;
    $("back").hidden = true;
    return;
  }
  sheet = due[0];
  screen = 0;
  answers = {};
  show();
}

function scaleOf(item) { return item.scale || sheet.scale; }

function show() {
  const block = sheet.blocks[screen];
  const total = answered + due.length;
  $("progress").textContent = `${sheet.title}: page ${screen + 1} of ${sheet.blocks.length} · ` +
    `questionnaire ${answered + 1} of ${total}`;
  $("block-title").textContent = block.title || sheet.title;
  const anchors = sheet.scale ? Object.entries(sheet.scale.anchors).map(([k, v]) => `${k}: ${v}`).join(" · ") : "";
  $("scale-note").textContent = anchors;
  $("items").replaceChildren(...block.items.map(itemView));
  $("back").hidden = screen === 0;
  $("next").hidden = false;
  $("next").textContent = screen === sheet.blocks.length - 1 ? "Send" : "Next";
  say("");
  check();
}

function itemView(item) {
  const scale = scaleOf(item);
  const box = document.createElement("fieldset");
  box.className = "item";
  box.dataset.item = item.id;
  const legend = document.createElement("legend");
  legend.textContent = item.text;
  box.append(legend);
  const choices = document.createElement("div");
  choices.className = "choices";
  const stepped = !item.choices && scale.integer && scale.max !== null && scale.max - scale.min <= 10;
  if (item.choices) {  // a demographic question: one of its bands
    for (const v of item.choices) {
      const b = Object.assign(document.createElement("button"), {type: "button", className: "choice", textContent: v});
      b.setAttribute("aria-pressed", String(answers[item.id] === v));
      b.onclick = () => { answers[item.id] = v; mark(box, b); };
      choices.append(b);
    }
  } else if (stepped) {
    if (item.left) choices.append(Object.assign(document.createElement("span"), {className: "anchor", textContent: item.left}));
    for (let v = scale.min; v <= scale.max; v++) {
      const b = document.createElement("button");
      b.type = "button";
      b.className = "choice";
      b.textContent = String(v);
      b.title = scale.anchors[String(v)] || "";
      b.setAttribute("aria-pressed", String(answers[item.id] === v));
      b.onclick = () => { answers[item.id] = v; mark(box, b); };
      choices.append(b);
    }
    if (item.right) choices.append(Object.assign(document.createElement("span"), {className: "anchor", textContent: item.right}));
  } else {
    const input = document.createElement("input");
    input.type = "number";
    input.inputMode = "decimal";
    input.className = "number";
    input.setAttribute("aria-label", item.text);
    input.placeholder = scale.max === null ? `${scale.min} or more` : `${scale.min} to ${scale.max}`;
    if (typeof answers[item.id] === "number") input.value = answers[item.id];
    input.oninput = () => {
      if (input.value === "") delete answers[item.id]; else answers[item.id] = Number(input.value);
      mark(box, null);
    };
    if (item.left || item.right) choices.append(`${item.left} `, input, ` ${item.right}`); else choices.append(input);
  }
  const decline = document.createElement("button");
  decline.type = "button";
  decline.className = "choice decline";
  decline.textContent = "prefer not to answer";
  decline.setAttribute("aria-pressed", String(answers[item.id] === PREFER_NOT));
  decline.onclick = () => { answers[item.id] = PREFER_NOT; mark(box, decline); };
  box.append(choices, decline);
  return box;
}

function mark(box, pressed) {
  for (const b of box.querySelectorAll("button.choice")) b.setAttribute("aria-pressed", String(b === pressed));
  check();
}

function check() {
  const block = sheet.blocks[screen];
  const missing = block.items.filter((i) => !(i.id in answers)).length;
  $("next").disabled = missing > 0;
  $("next").title = missing ? `${missing} item${missing > 1 ? "s" : ""} without an answer` : "";
}

$("back").onclick = () => { if (screen > 0) { screen--; show(); } };
$("next").onclick = async () => {
  if (screen < sheet.blocks.length - 1) { screen++; show(); return; }
  $("next").disabled = true;
  try {
    await ros.callService(names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
      questionnaire: sheet.questionnaire, condition: sheet.condition, answers_json: JSON.stringify(answers)});
  } catch (err) {
    say(err.message, true);  // e.g. an answer out of its scale, naming the item: go back to it and correct it
    $("next").disabled = false;
    return;
  }
  say(`${sheet.title}: sent, thank you.`);
  load();
};
