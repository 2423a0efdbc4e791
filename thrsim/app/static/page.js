// What every trainer page shares: the WebSocket to its mode (reconnecting), toasts, panel text
// written only when it changed, the tracking list, the session's label and the "session saved" link.
// Each page is its trainee's own session; `?observe=SESSION_ID` watches another's, read-only.

export const $ = (id) => document.getElementById(id);

export const OBSERVE = new URLSearchParams(location.search).get("observe");

export function toast(text, kind = "") {
  const item = document.createElement("div");
  item.className = `toast ${kind}`;
  item.textContent = text;
  $("toasts").appendChild(item);
  setTimeout(() => item.remove(), kind === "error" ? 5000 : 2500);
}

// States arrive at every server tick (the hello's tick_hz) and mostly repeat what is shown: the
// panels are written only where a value changed, since each write has the browser lay out and
// repaint them (CPU the drawing needs).
export function setText(id, text) {
  const element = $(id);
  if (element.textContent !== text) element.textContent = text;
}

// Plain names of the tracked tools.
export const TOOL_NAMES = { Reference: "Pelvis marker array", Probe: "Probe", Reamer: "Reamer" };

export const REASONS = { tracked: "tracked", outside_volume: "outside the volume", angle: "turned beyond 45°", occluded: "line of sight blocked", stale: "no recent pose", missing: "not in use" };

// The tracking list, rebuilt only when a tool's state changed.
let shownTools = "";
export function showTools(states) {
  const look = JSON.stringify(Object.entries(states).map(([name, t]) => [name, t.reason, t.tracked, t.angle_deg?.toFixed(0)]));
  if (look === shownTools) return;
  shownTools = look;
  const list = $("tools");
  list.innerHTML = "";
  for (const [name, t] of Object.entries(states)) {
    const li = document.createElement("li");
    const dot = document.createElement("span");
    dot.className = `dot ${t.reason === "missing" ? "none" : t.tracked ? "on" : "off"}`;
    li.append(dot, `${TOOL_NAMES[name] ?? name}: ${REASONS[t.reason] ?? t.reason}`);
    if (t.angle_deg !== null && t.angle_deg !== undefined) li.append(` (${t.angle_deg.toFixed(0)}°)`);
    li.dataset.tool = name;
    li.dataset.reason = t.reason;
    list.appendChild(li);
  }
}

// The angle read-out box: its border in the safe-zone colour.
export function showAngles(s) {
  const angles = s.angles ? s.angles[s.definition] : null;
  const boxClass = `angles ${s.zone ? s.zone.colour : "unknown"}`;
  if ($("angles").className !== boxClass) $("angles").className = boxClass;
  setText("inclination", angles ? `${angles[0].toFixed(1)}°` : "—");
  setText("anteversion", angles ? `${angles[1].toFixed(1)}°` : "—");
  setText("zone-text", !s.zone ? s.note : s.zone.inside ? "inside the safe zone" : `${s.zone.distance_deg.toFixed(1)}° outside the safe zone`);
}

export function showSaved(message) {
  const box = $("saved");
  box.classList.remove("hidden");
  box.innerHTML = "";
  const link = document.createElement("a");
  link.href = message.report;
  link.target = "_blank";
  link.id = "report-link";
  link.textContent = "Open the assessment report";
  const rate = document.createElement("button");
  rate.id = "rate-session";
  rate.textContent = "Rate this session";
  rate.title = "An optional questionnaire: how realistic and useful the trainer felt";
  rate.addEventListener("click", () => openQuestionnaire(message.session));
  box.append("Session saved: ", link, " · ", rate);
  toast("session saved", "good");
}

// ---- the trainee's name and the post-session questionnaire ---------------------------------------

const TRAINEE_KEY = "thrsim-trainee";
// As the server checks it (thrsim.app.controls.TRAINEE_PATTERN): it names the trainee's record page.
const TRAINEE_PATTERN = /^[A-Za-z0-9][A-Za-z0-9 ._-]{0,39}$/;

// Who trains: asked in the first panel until given, remembered by this browser, and sent again to
// every new session of the page (after each end), so each session file names its trainee.
export function askTrainee(send) {
  let box = $("trainee");
  if (!box) {
    box = document.createElement("section");
    box.id = "trainee";
    box.innerHTML = '<h2>Who is training?</h2><form id="trainee-form"><label>Your name or trainee ID <input id="trainee-id" maxlength="40" autocomplete="off"></label>' +
      '<button id="trainee-save" class="primary" type="submit">Start as this trainee</button></form><div id="trainee-shown" class="muted"></div>';
    $("steps").prepend(box);
    $("trainee-id").addEventListener("keydown", (e) => e.stopPropagation()); // typing is not a shortcut
    $("trainee-form").addEventListener("submit", (e) => {
      e.preventDefault();
      const id = $("trainee-id").value.trim();
      if (!TRAINEE_PATTERN.test(id)) {
        toast("a name or ID of 1–40 letters, digits, spaces, dots, dashes or underscores, starting with a letter or digit", "error");
        return;
      }
      localStorage.setItem(TRAINEE_KEY, id);
      $("trainee-id").blur();
      sendTrainee(send);
    });
  }
  sendTrainee(send);
}

function sendTrainee(send) {
  const id = localStorage.getItem(TRAINEE_KEY);
  const known = id !== null && TRAINEE_PATTERN.test(id);
  $("trainee").classList.toggle("asking", !known);
  $("trainee-form").classList.toggle("hidden", known);
  $("trainee-shown").innerHTML = "";
  if (!known) return;
  const link = document.createElement("a");
  link.href = `/trainee/${encodeURIComponent(id.toLowerCase())}`;
  link.target = "_blank";
  link.textContent = "your record";
  const change = document.createElement("button");
  change.textContent = "Change";
  change.addEventListener("click", () => { localStorage.removeItem(TRAINEE_KEY); $("trainee-id").value = id; sendTrainee(send); $("trainee-id").focus(); });
  $("trainee-shown").append(`Training as ${id} · `, link, " ", change);
  send({ type: "trainee", id });
}

// The optional questionnaire after a session (Likert 1–5, the thesis's face-validation items):
// stored in the saved session's file, exported with its metrics.
async function openQuestionnaire(session) {
  const response = await fetch("/api/questionnaire");
  const { items, scale } = await response.json();
  let dialog = $("questionnaire");
  if (dialog) dialog.remove();
  dialog = document.createElement("dialog");
  dialog.id = "questionnaire";
  const rows = Object.entries(items).map(([item, statement]) => {
    const choices = Object.entries(scale).map(([value, words]) =>
      `<label title="${words}"><input type="radio" name="${item}" value="${value}"> ${value}</label>`).join("");
    return `<tr><td>${statement}</td><td class="likert">${choices}</td></tr>`;
  }).join("");
  dialog.innerHTML = `<form method="dialog"><h2>How was this session?</h2><p class="hint">1 strongly disagree · 3 neutral · 5 strongly agree. Every item is optional.</p>` +
    `<table>${rows}</table><label>Comment <textarea id="q-comment" maxlength="1000" rows="2"></textarea></label>` +
    `<div class="row"><button id="q-send" class="primary" value="send">Send answers</button><button value="cancel">Not now</button></div></form>`;
  document.body.append(dialog);
  dialog.addEventListener("keydown", (e) => e.stopPropagation());
  dialog.addEventListener("close", async () => {
    if (dialog.returnValue !== "send") return;
    const answers = {};
    for (const input of dialog.querySelectorAll("input[type=radio]:checked")) answers[input.name] = Number(input.value);
    const reply = await fetch(`/api/sessions/${session}/questionnaire`, {
      method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify({ answers, comment: $("q-comment").value }),
    });
    const body = await reply.json();
    toast(reply.ok ? "thank you: your answers are saved with the session" : `answers not saved: ${body.error}`, reply.ok ? "good" : "error");
  });
  dialog.showModal();
}

// Opens /ws/<mode> (this page's own session, or the one it observes), retrying every second after a
// drop (a new session: the server ends a session whose page left), every 5 s while the trainer is
// full, never once the observed session is over. `onText` gets each decoded JSON message,
// `onBinary` each binary frame (ArrayBuffer), `onOpen` runs on every (re)connection.
// Returns send(message), which drops messages while disconnected and on an observer's page.
export function connectMode(mode, stats, { onText, onBinary = null, onOpen = null }) {
  let socket = null;
  const connect = () => {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    socket = new WebSocket(`${scheme}://${location.host}/ws/${mode}` + (OBSERVE ? `?observe=${encodeURIComponent(OBSERVE)}` : ""));
    socket.binaryType = "arraybuffer";
    socket.onopen = () => {
      stats.connected = true;
      $("connection").textContent = "connected";
      $("connection").className = "pill ok";
      if (onOpen) onOpen();
    };
    socket.onclose = (event) => {
      stats.connected = false;
      $("connection").className = "pill bad";
      if (event.code === 4404 || event.code === 4410) { // nothing (more) to observe
        $("connection").textContent = "session over";
        return;
      }
      $("connection").textContent = event.code === 4429 ? "trainer full — retrying" : "disconnected — retrying";
      setTimeout(connect, event.code === 4429 ? 5000 : 1000);
    };
    socket.onmessage = (event) => {
      if (event.data instanceof ArrayBuffer) {
        if (onBinary) onBinary(event.data);
      } else {
        onText(JSON.parse(event.data));
      }
    };
  };
  connect();
  return (message) => {
    if (stats.role === "observer") return; // the server refuses an observer's controls
    if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
  };
}

// A hello: the session and this page's role in it. An observer's controls are disabled; a
// trainee's page offers the link an instructor opens to observe it.
export function showHello(message, stats) {
  stats.hello = message;
  stats.role = message.role;
  const observer = message.role === "observer";
  document.body.classList.toggle("observer", observer);
  for (const control of document.querySelectorAll("#steps button, #steps input, #steps select, #end")) control.disabled = observer;
  const label = $("session-id");
  label.innerHTML = "";
  if (observer) {
    label.append(`observing session ${message.session} (read-only)`);
  } else {
    const link = document.createElement("a");
    link.href = message.observe;
    link.target = "_blank";
    link.id = "observe-link";
    link.textContent = "observe";
    label.append(`session ${message.session} · `, link);
  }
  $("tracker").textContent = message.igtl ? `OpenIGTLink ${message.igtl[0]}:${message.igtl[1]}` : "";
}

// The messages every mode answers alike: acknowledgements, errors and the saved session.
export function commonMessage(message, stats) {
  if (message.type === "ack") {
    stats.acks.push(message.message);
  } else if (message.type === "error" || message.type === "refused") {
    stats.errors.push(message.message);
    toast(message.message, "error");
    if (stats.role !== "observer") $("end").disabled = false;
  } else if (message.type === "session_over") {
    stats.over = message.message;
    toast(message.message);
  } else if (message.type === "session_saved") {
    stats.saved = message;
    showSaved(message);
  } else {
    return false;
  }
  return true;
}
