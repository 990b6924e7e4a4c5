// The live viewer: joins the zenoh network through the remote-api plugin's WebSocket
// (@eclipse-zenoh/zenoh-ts), lists the open envs of every server (ServerInfo.envs), follows one
// env's publications (states, risk_graph, events; protocol/SPEC.md section 11) across its
// resets, and draws them. It subscribes to the one env it shows, so a server steps every other
// env without encoding anything for it (the server publishes only what somebody listens to).
//
// URL parameters: ws (the plugin's WebSocket; default: what viewer-config.json of the server
// that serves the page says, else ws://<this host>:10000), prefix (default likewise, else
// sharedspace), env (an env id to follow at once), k (strongest edges drawn per agent, default 2),
// follow (0: the camera stays where the episode's fit put it; default: it follows the car).
import { Config, Session } from "@eclipse-zenoh/zenoh-ts";
import { decodePayload, readRiskGraph, readStates, strongestEdges } from "./wire.js";
import { drawFrame, fitView, toWorld } from "./draw.js";

const params = new URLSearchParams(location.search);
let WS = params.get("ws") || `ws://${location.hostname || "127.0.0.1"}:10000`;
let PREFIX = params.get("prefix") || "sharedspace";

// `python -m sharedspace.viewer` serves the WebSocket and prefix it chose beside the page, so the
// page opened at its root URL connects to the right port; a page served by anything else keeps
// the defaults above.
async function loadServedConfig() {
  try {
    const reply = await fetch("viewer-config.json", { cache: "no-store" });
    if (!reply.ok) return;
    const served = await reply.json();
    if (!params.get("ws") && served.ws) WS = served.ws;
    if (!params.get("prefix") && served.prefix) PREFIX = served.prefix;
  } catch (e) {
    console.info("no viewer-config.json beside the page; defaults", e);
  }
}
const TRAIL = 40; // points of a vehicle's trail kept (20 s at 2 Hz)

const $ = (id) => document.getElementById(id);
const canvas = $("scene");
const ctx = canvas.getContext("2d");
const state = {
  session: null,
  envId: params.get("env") || "",
  subscribers: [],
  frame: null, // latest readStates
  graph: null, // latest readRiskGraph
  outcome: "",
  trails: new Map(),
  episode: null,
  view: null,
  userMoved: false,
  // The camera keeps the followed car at the centre (the ego, or a vehicle clicked on) so that a
  // car leaving its recorded path stays in the picture; a drag of the scene stops that.
  follow: params.get("follow") !== "0",
  paused: false,
  autoFollow: !params.get("env"), // switch to another env when the followed one closes
  selected: null,
  frames: 0,
};
if (params.get("k") !== null) $("topk").value = params.get("k");

function setConnection(text, ok) {
  const el = $("connection");
  el.textContent = text;
  el.className = ok ? "ok" : "bad";
}

async function follow(envId) {
  for (const s of state.subscribers) await s.undeclare().catch(() => {});
  state.subscribers = [];
  state.envId = envId;
  state.frame = state.graph = null;
  state.trails = new Map();
  state.episode = null;
  state.outcome = "";
  state.userMoved = false;
  requestRender();
  $("episode").dataset.env = envId;
  $("outcome").textContent = envId ? "waiting for its next step" : "";
  if (!envId) return;
  const topic = (t) => `${PREFIX}/env/${envId}/${t}`;
  const sub = async (t, handle) =>
    state.subscribers.push(
      await state.session.declareSubscriber(topic(t), {
        handler: (sample) => {
          try {
            handle(decodePayload(sample.payload().toBytes()));
          } catch (e) {
            console.error(`bad ${t} message`, e);
          }
        },
      }),
    );
  await sub("states", onStates);
  await sub("risk_graph", (m) => {
    if (state.paused) return;
    state.graph = readRiskGraph(m);
    requestRender();
  });
  await sub("events", (m) => {
    for (const e of m.events || []) {
      if (e.kind === "episode_end" && e.outcome) state.outcome = e.outcome;
    }
  });
}

function onStates(msg) {
  if (state.paused) return;
  const frame = readStates(msg);
  if (state.episode !== frame.episode) {
    state.episode = frame.episode;
    state.trails = new Map();
    state.outcome = "";
    if (!state.userMoved) state.view = null; // refit to the new episode's scene
  }
  // The outcome from the learner's reward terms too: at more steps per second than the viewer's
  // rate the router samples the events, and the episode_end event may be among those dropped.
  const r = frame.rewards;
  if (r && r.agents.length) {
    if (r.terms.success && r.terms.success[0] > 0) state.outcome = "success";
    else if (r.terms.collision && r.terms.collision[0] < 0) state.outcome = "collision";
  }
  for (const a of frame.agents) {
    if (a.kind !== "vehicle") continue;
    const pts = state.trails.get(a.id) || [];
    pts.push([a.x, a.y]);
    if (pts.length > TRAIL) pts.shift();
    state.trails.set(a.id, pts);
  }
  state.frame = frame;
  state.frames++;
  requestRender();
}

async function refreshEnvs() {
  const receiver = await state.session.get(`${PREFIX}/server/*/info`, { payload: new Uint8Array() });
  const envs = [];
  if (receiver) {
    for await (const reply of receiver) {
      const r = reply.result();
      if (typeof r.payload !== "function") continue; // a ReplyError
      const info = decodePayload(r.payload().toBytes());
      if (!info.ok) continue;
      for (const e of info.ok.envs || []) envs.push({ ...e, server: info.ok.server_id });
    }
  }
  const select = $("envs");
  const current = state.envId;
  select.replaceChildren(
    ...(envs.length ? [] : [new Option("(no open env)", "")]),
    ...envs.map((e) => new Option(`${e.env_id}  (${e.client_id})`, e.env_id)),
  );
  const open = envs.some((e) => e.env_id === current);
  if (envs.length && (!current || (!open && state.autoFollow))) {
    // Nothing followed yet, or the env it picked itself closed (a trainer restarted): follow
    // the first open env. An env the user picked (or named in the address) is kept.
    await follow(envs[0].env_id);
    select.value = envs[0].env_id;
  } else if (open) select.value = current;
  else if (current) select.add(new Option(`${current} (closed)`, current), 0), (select.value = current);
}

function resize() {
  const r = canvas.getBoundingClientRect();
  canvas.width = Math.max(1, Math.round(r.width * devicePixelRatio));
  canvas.height = Math.max(1, Math.round(r.height * devicePixelRatio));
  requestRender();
}

// Frames are drawn on demand (a message, a zoom, a click), at most once per display frame; an
// idle page schedules nothing, so watching costs the machine little beside the training.
let renderPending = false;
function requestRender() {
  if (renderPending) return;
  renderPending = true;
  requestAnimationFrame(() => {
    renderPending = false;
    render();
  });
}

function render() {
  if (!state.frame) return;
  const started = performance.now();
  try {
    draw();
  } finally {
    state.renders = (state.renders || 0) + 1;
    state.renderMs = (state.renderMs || 0) + performance.now() - started;
  }
}

/** The agent the camera follows: the selected vehicle, else the ego (the first external
 * vehicle), else an external pedestrian, else the first vehicle; null when there is none. */
function followedCar(frame) {
  const cars = frame.agents.filter((a) => a.kind === "vehicle");
  return (
    cars.find((a) => a.id === state.selected) ||
    cars.find((a) => a.external) ||
    frame.agents.find((a) => a.external) ||
    cars[0] ||
    null
  );
}

function draw() {
  const { width, height } = canvas;
  const frame = state.frame;
  if (!state.view) state.view = fitView(frame, state.trails, width, height);
  const car = state.follow ? followedCar(frame) : null;
  if (car) [state.view.cx, state.view.cy] = [car.x, car.y];
  const all = state.graph && state.graph.episode === frame.episode ? state.graph.edges : [];
  const present = new Set(frame.agents.map((a) => a.id));
  const live = all.filter((e) => present.has(e.src) && present.has(e.dst));
  const edges = strongestEdges(live, Number($("topk").value));
  const amax = Math.max(1e-9, ...live.map((e) => e.a));
  const drawn = drawFrame(ctx, width, height, state.view, frame, edges, amax, state.trails, state.selected);
  $("amax").textContent = amax.toFixed(2);
  $("scenario").textContent = frame.scenario;
  $("ep").textContent = frame.episode;
  $("step").textContent = frame.step;
  $("time").textContent = `${frame.t.toFixed(1)} s`;
  $("nagents").textContent = frame.agents.length;
  $("nedges").textContent = `${live.length} (${drawn})`;
  $("outcome").textContent = state.outcome || "running";
  const ep = $("episode").dataset;
  Object.assign(ep, {
    env: frame.envId, episode: frame.episode, step: frame.step, agents: frame.agents.length,
    edges: live.length, edgesDrawn: drawn, frames: state.frames, outcome: state.outcome,
  });
  renderRewards(frame);
  renderSelected(frame, live);
}

function renderRewards(frame) {
  const rows = [];
  const r = frame.rewards;
  if (r) {
    r.agents.forEach((id, k) => {
      rows.push(`<tr><td><b>agent ${id}</b></td><td class="num">${r.reward[k].toFixed(3)}</td></tr>`);
      for (const [name, arr] of Object.entries(r.terms)) {
        rows.push(`<tr><td>&nbsp;&nbsp;${name}</td><td class="num">${arr[k].toFixed(3)}</td></tr>`);
      }
      rows.push(`<tr><td>&nbsp;&nbsp;return so far</td><td class="num">${r.returns[k].toFixed(2)}</td></tr>`);
    });
  }
  $("rewards").innerHTML = rows.join("") || "<tr><td>(episode start)</td></tr>";
}

function agentSummary(a, edges) {
  const out = edges.filter((e) => e.src === a.id), inc = edges.filter((e) => e.dst === a.id);
  const max = (list, f) => (list.length ? Math.max(...list.map(f)) : 0);
  const speed = Math.hypot(a.vx, a.vy);
  return (
    `${a.kind} ${a.id}${a.external ? " (learner)" : a.reactive ? " (reactive)" : a.kind === "vehicle" ? " (replayed)" : ""}\n` +
    `speed ${speed.toFixed(2)} m/s\n` +
    `its beliefs: ${out.length} agents, max u ${max(out, (e) => e.u).toFixed(3)}, ` +
    `max psi ${max(out, (e) => e.psi).toFixed(3)}\n` +
    `about it: max u ${max(inc, (e) => e.u).toFixed(3)}, max psi ${max(inc, (e) => e.psi).toFixed(3)}`
  );
}

function renderSelected(frame, edges) {
  const a = frame.agents.find((x) => x.id === state.selected);
  $("selected").textContent = a ? agentSummary(a, edges) : "click an agent";
  $("selected").style.whiteSpace = "pre-wrap";
}

function agentAt(px, py) {
  if (!state.frame || !state.view) return null;
  const [x, y] = toWorld(state.view, canvas.width, canvas.height, px, py);
  let best = null, bestD = Infinity;
  for (const a of state.frame.agents) {
    const d = Math.hypot(a.x - x, a.y - y);
    if (d < Math.max(a.length / 2 + 0.5, 8 / state.view.scale) && d < bestD) (best = a), (bestD = d);
  }
  return best;
}

function setFollow(on) {
  state.follow = on;
  $("follow").checked = on;
  requestRender();
}

function setupInteraction() {
  let drag = null;
  const px = (ev) => [ev.offsetX * devicePixelRatio, ev.offsetY * devicePixelRatio];
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    if (!state.view) return;
    const [x, y] = toWorld(state.view, canvas.width, canvas.height, ...px(ev));
    const f = Math.exp(-ev.deltaY * 0.0015);
    state.view.scale *= f;
    state.view.cx = x - (x - state.view.cx) / f;
    state.view.cy = y - (y - state.view.cy) / f;
    state.userMoved = true;
    requestRender();
  });
  canvas.addEventListener("mousedown", (ev) => {
    drag = { start: px(ev), moved: false };
    canvas.classList.add("dragging");
  });
  window.addEventListener("mouseup", (ev) => {
    canvas.classList.remove("dragging");
    if (drag && !drag.moved && ev.target === canvas) {
      const a = agentAt(...px(ev));
      state.selected = a ? a.id : null;
      requestRender();
    }
    drag = null;
  });
  canvas.addEventListener("mousemove", (ev) => {
    const [x, y] = px(ev);
    if (drag && state.view) {
      const dx = x - drag.start[0], dy = y - drag.start[1];
      if (Math.abs(dx) + Math.abs(dy) > 2) drag.moved = true;
      state.view.cx -= dx / state.view.scale;
      state.view.cy += dy / state.view.scale;
      drag.start = [x, y];
      state.userMoved = true;
      setFollow(false);
      requestRender();
    }
    const tip = $("tooltip");
    const a = drag ? null : agentAt(x, y);
    if (a && state.frame) {
      const edges = state.graph ? state.graph.edges : [];
      tip.textContent = agentSummary(a, edges);
      tip.style.left = `${ev.offsetX + 12}px`;
      tip.style.top = `${ev.offsetY + 12}px`;
      tip.style.display = "block";
    } else tip.style.display = "none";
  });
  $("pause").addEventListener("click", () => {
    state.paused = !state.paused;
    $("pause").textContent = state.paused ? "Resume" : "Pause";
  });
  $("fit").addEventListener("click", () => {
    state.view = null;
    state.userMoved = false;
    requestRender();
  });
  $("follow").checked = state.follow;
  $("follow").addEventListener("change", (ev) => setFollow(ev.target.checked));
  $("topk").addEventListener("change", () => requestRender());
  $("envs").addEventListener("change", (ev) => {
    state.autoFollow = false;
    follow(ev.target.value);
  });
  window.addEventListener("resize", () => {
    resize();
    if (!state.userMoved) state.view = null;
  });
}

async function main() {
  await loadServedConfig();
  resize();
  setupInteraction();
  window.viewer = state; // for tests and the console
  // zenoh-ts keeps retrying an unreachable WebSocket; say so after a few seconds and go on
  // waiting, so a viewer opened before its router still connects.
  const opening = Session.open(new Config(WS));
  const slow = setTimeout(
    () => setConnection(`cannot reach ${WS} (is \`make view\` running?); retrying`, false),
    4000,
  );
  try {
    state.session = await opening;
  } catch (e) {
    setConnection(`cannot reach ${WS}: ${e}`, false);
    return;
  } finally {
    clearTimeout(slow);
  }
  setConnection(`${WS}`, true);
  if (state.envId) await follow(state.envId);
  const poll = async () => {
    try {
      await refreshEnvs();
    } catch (e) {
      console.error("env list", e);
    }
    setTimeout(poll, 2000);
  };
  poll();
}

main();
