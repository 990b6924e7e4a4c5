// Decoding of the server's msgpack messages (protocol/SPEC.md sections 2 and 11).
import { decode } from "@msgpack/msgpack";

const TYPED = {
  "<f8": Float64Array,
  "<f4": Float32Array,
  "<u4": Uint32Array,
  "<u8": BigUint64Array,
  "|u1": Uint8Array,
};

/** A protocol array `{dtype, shape, data}` as a typed array (row-major) plus its shape. */
export function toArray(m) {
  if (m == null) return null;
  const Typed = TYPED[m.dtype];
  if (!Typed) throw new Error(`unsupported dtype ${m.dtype}`);
  // Copy: msgpack's bin slices are not aligned for 4- and 8-byte views.
  const bytes = m.data.slice();
  const arr = new Typed(bytes.buffer, bytes.byteOffset, bytes.byteLength / Typed.BYTES_PER_ELEMENT);
  arr.shape = m.shape;
  return arr;
}

/** The bytes of a zenoh sample's payload, decoded from msgpack. */
export function decodePayload(bytes) {
  return decode(bytes);
}

/** The StatesMsg fields read into named agent properties below; every other per-agent array
 * (first dimension = the agent count, e.g. `reactive`) becomes a property of the same name by
 * itself: a row for a 2-D array, a number for a 1-D one. A new per-agent field of StatesMsg
 * therefore reaches draw.js without an edit here. */
const NAMED_STATE_FIELDS = new Set([
  "ids", "kinds", "positions", "velocities", "headings", "sizes", "goals", "external",
]);

/** A StatesMsg as plain arrays: one entry per agent. */
export function readStates(msg) {
  const ids = toArray(msg.ids);
  const kinds = toArray(msg.kinds);
  const pos = toArray(msg.positions);
  const vel = toArray(msg.velocities);
  const head = toArray(msg.headings);
  const sizes = toArray(msg.sizes);
  const goals = toArray(msg.goals);
  const external = toArray(msg.external);
  const perAgent = [];
  for (const [name, value] of Object.entries(msg)) {
    if (NAMED_STATE_FIELDS.has(name) || value == null || value.dtype === undefined) continue;
    const arr = toArray(value);
    if (arr.shape.length >= 1 && arr.shape[0] === ids.length) perAgent.push([name, arr]);
  }
  const agents = [];
  for (let i = 0; i < ids.length; i++) {
    agents.push({
      id: ids[i],
      kind: kinds[i] === 0 ? "vehicle" : "pedestrian",
      x: pos[2 * i], y: pos[2 * i + 1],
      vx: vel[2 * i], vy: vel[2 * i + 1],
      heading: head[i],
      length: sizes ? sizes[2 * i] : (kinds[i] === 0 ? 4.5 : 0.6),
      width: sizes ? sizes[2 * i + 1] : (kinds[i] === 0 ? 1.8 : 0.6),
      goal: goals ? [goals[2 * i], goals[2 * i + 1]] : null,
      external: external ? external[i] === 1 : false,
    });
    for (const [name, arr] of perAgent) {
      const width = arr.length / ids.length;
      agents[i][name] = width === 1 ? Number(arr[i]) : Array.from(arr.slice(i * width, (i + 1) * width));
    }
  }
  let rewards = null;
  if (msg.rewards) {
    const r = msg.rewards;
    const terms = {};
    for (const [name, arr] of Object.entries(r.terms)) terms[name] = toArray(arr);
    rewards = {
      agents: Array.from(toArray(r.agents)),
      reward: toArray(r.reward),
      returns: toArray(r.returns),
      terms,
    };
  }
  return {
    envId: msg.env_id, episode: Number(msg.episode), step: msg.step, t: msg.t,
    scenario: msg.scenario || "", agents, rewards,
  };
}

/** A RiskGraphMsg as an edge list. */
export function readRiskGraph(msg) {
  const src = toArray(msg.src), dst = toArray(msg.dst);
  const psi = toArray(msg.psi), u = toArray(msg.u), a = toArray(msg.a);
  const edges = [];
  for (let e = 0; e < src.length; e++) {
    edges.push({ src: src[e], dst: dst[e], psi: psi[e], u: u[e], a: a[e] });
  }
  return { episode: Number(msg.episode), step: msg.step, lambda: msg.lambda, edges };
}

/** The strongest `k` outgoing edges of every observer (all when k is 0). */
export function strongestEdges(edges, k) {
  if (!k) return edges.slice();
  const bySrc = new Map();
  for (const e of edges) {
    if (!bySrc.has(e.src)) bySrc.set(e.src, []);
    bySrc.get(e.src).push(e);
  }
  const out = [];
  for (const list of bySrc.values()) {
    list.sort((p, q) => q.a - p.a);
    out.push(...list.slice(0, k));
  }
  return out;
}
