// What every trainer page shares: the WebSocket to its mode (reconnecting), toasts, panel text
// written only when it changed, the tracking list and the "session saved" link.

export const $ = (id) => document.getElementById(id);

export function toast(text, kind = "") {
  const item = document.createElement("div");
  item.className = `toast ${kind}`;
  item.textContent = text;
  $("toasts").appendChild(item);
  setTimeout(() => item.remove(), kind === "error" ? 5000 : 2500);
}

// States arrive at 60 Hz and mostly repeat what is shown: the panels are written only where a
// value changed, since each write has the browser lay out and repaint them (CPU the drawing needs).
export function setText(id, text) {
  const element = $(id);
  if (element.textContent !== text) element.textContent = text;
}

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
    li.append(dot, `${name}: ${REASONS[t.reason] ?? t.reason}`);
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
  box.append("Session saved: ", link);
  toast("session saved", "good");
}

// Opens /ws/<mode>, retrying every second after a drop. `onText` gets each decoded JSON message,
// `onBinary` each binary frame (ArrayBuffer), `onOpen` runs on every (re)connection.
// Returns send(message), which drops messages while disconnected.
export function connectMode(mode, stats, { onText, onBinary = null, onOpen = null }) {
  let socket = null;
  const connect = () => {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    socket = new WebSocket(`${scheme}://${location.host}/ws/${mode}`);
    socket.binaryType = "arraybuffer";
    socket.onopen = () => {
      stats.connected = true;
      $("connection").textContent = "connected";
      $("connection").className = "pill ok";
      if (onOpen) onOpen();
    };
    socket.onclose = () => {
      stats.connected = false;
      $("connection").textContent = "disconnected — retrying";
      $("connection").className = "pill bad";
      setTimeout(connect, 1000);
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
    if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
  };
}

// The messages every mode answers alike: acknowledgements, errors and the saved session.
export function commonMessage(message, stats) {
  if (message.type === "ack") {
    stats.acks.push(message.message);
  } else if (message.type === "error") {
    stats.errors.push(message.message);
    toast(message.message, "error");
  } else if (message.type === "session_saved") {
    stats.saved = message;
    showSaved(message);
  } else {
    return false;
  }
  return true;
}
