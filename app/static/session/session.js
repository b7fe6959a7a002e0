// The scanning-session page: each dropped scan is solved once, by POST /v1/correspondence (its
// spectrum and where it lies on the template); after that only spectra and region tokens are
// sent. After every scan the page asks /v1/localize (JSON and the coloured template as PLY),
// /v1/retrieve and /v1/reconstruct (the rebuilt body as PLY, its height and spectrum check in
// headers) for the union of all parts so far. With "registered scans" (one scanner's views: one
// frame, one pose) the scans go to a scanning session of the service (POST /v1/sessions, then
// POST /v1/sessions/{id}/views), which solves their union once on the views themselves; the
// union routes are then asked about that union (its spectrum with its region token). With
// "whole-body scans" each scan's holes are capped before its solve (cap_holes=true): a whole
// body scanned standing is solved as the closed body.
import * as THREE from "three";
import { OrbitControls } from "/static/vendor/three/OrbitControls.js";
import { PLYLoader } from "/static/vendor/three/PLYLoader.js";

const parts = []; // {name, eigenvalues, warnings, region, file}
let session = null; // registered scans: the service's session they were added to, as it last answered
const $ = (id) => document.getElementById(id);
const SVG = "http://www.w3.org/2000/svg";
const RETRIEVED = 25; // shapes asked of /v1/retrieve, grouped by person
const SHOWN = 5; // people listed
const OPEN_LAMBDA = 0.05; // 1/m²: a first Dirichlet eigenvalue above it is an open surface's (a closed body's is 0)

function setStatus(text, problem = false) {
  $("status").textContent = text;
  $("status").classList.toggle("problem", problem);
}

// What the union routes are asked about: every part's spectrum, and where each lies on the
// template when every part was placed there (its region token from /v1/correspondence), so the
// union is localized, and each step's overlap measured, on the template; for registered scans,
// the session's union itself with what the scans cover together.
function spectraForm() {
  const form = new FormData();
  const operands = session ? [{ eigenvalues: session.eigenvalues, region: session.region_token }] : parts;
  form.append("spectra", JSON.stringify(operands.map((part) => part.eigenvalues)));
  if (operands.every((part) => part.region)) form.append("regions", JSON.stringify(operands.map((part) => part.region)));
  return form;
}

// What the served models do (GET /v1/models): whether uploaded parts are placed on the template.
const served = fetch("/v1/models").then(answer);

async function answer(response) {
  const body = response.headers.get("content-type")?.includes("json") ? await response.json() : null;
  if (!response.ok) {
    throw new Error(body ? `${body.title}: ${body.detail}` : `HTTP ${response.status}`);
  }
  return body;
}

async function addScan(file) {
  setStatus(`Solving ${file.name}…`);
  try {
    const part = $("registered").checked ? await addedToSession(file) : await solved(file);
    parts.push({ ...part, name: file.name, file });
    $("registered").disabled = true; // one kind of session: every scan registered, or none
    await refresh();
  } catch (error) {
    setStatus(`${file.name}: ${error.message}`, true);
  }
}

// A scan solved on its own: placed on the template (one solve gives its spectrum and its region),
// or, a whole-body scan, its holes capped.
async function solved(file) {
  const form = new FormData();
  form.append("file", file, file.name);
  const whole = $("whole").checked;
  const placed = (await served).correspondence && !whole;
  const query = `units=${$("units").value}${whole ? "&cap_holes=true" : ""}`;
  const report = await answer(await fetch(`${placed ? "/v1/correspondence" : "/v1/spectrum"}?${query}`, { method: "POST", body: form }));
  return { eigenvalues: report.eigenvalues, warnings: report.warnings, region: placed ? report.region.token : undefined };
}

// A registered scan added to the page's session (made with the first scan); the session answers
// the union of all its views. A scan the service refuses leaves the session as it was.
async function addedToSession(file) {
  if (session === null) {
    const options = { registered: true, units: $("units").value };
    const made = await fetch("/v1/sessions", { method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(options) });
    session = await answer(made);
  }
  const form = new FormData();
  form.append("file", file, file.name);
  session = await answer(await fetch(`/v1/sessions/${session.id}/views`, { method: "POST", body: form }));
  const view = session.views[session.views.length - 1];
  return { eigenvalues: view.eigenvalues, warnings: view.warnings, region: view.region_token };
}

// A registered session without one of its scans: a new session of the scans left, in their order.
async function resession() {
  const ended = session;
  session = null;
  for (const part of parts) await addedToSession(part.file);
  if (ended) fetch(`/v1/sessions/${ended.id}`, { method: "DELETE" });
}

async function removeScan(index) {
  const [removed] = parts.splice(index, 1);
  try {
    if ($("registered").checked) await resession();
    await refresh();
  } catch (error) {
    setStatus(`removing ${removed.name}: ${error.message}`, true);
  }
}

// The page as it was before any scan.
function cleared() {
  for (const id of ["parts", "warnings", "coverage", "matches", "plot", "measurements"]) $(id).replaceChildren();
  for (const id of ["located", "missing", "matches-note", "rebuilt-note", "measurements-note"]) $(id).textContent = "";
  covered.clear();
  rebuiltView.clear();
  $("registered").disabled = false;
  document.body.dataset.parts = "0";
  setStatus("No scan yet.");
}

async function refresh() {
  if (parts.length === 0) {
    cleared();
    return;
  }
  const item = (part, index) => {
    const li = document.createElement("li");
    li.textContent = `${part.name}: λ₁ = ${part.eigenvalues[0].toFixed(3)}`;
    for (const warning of part.warnings) {
      const note = document.createElement("span");
      note.className = "warning";
      note.textContent = ` — ${warning}`;
      li.append(note);
    }
    const remove = document.createElement("button");
    remove.type = "button";
    remove.className = "remove";
    remove.textContent = "remove";
    remove.title = `Leave ${part.name} out of the union`;
    remove.addEventListener("click", () => removeScan(index));
    li.append(" ", remove);
    return li;
  };
  $("parts").replaceChildren(...parts.map(item));
  setStatus(`Uniting ${parts.length} part${parts.length > 1 ? "s" : ""}…`);
  const [region, ply, found, rebuilt, body] = await Promise.all([
    fetch("/v1/localize", { method: "POST", body: spectraForm() }).then(answer),
    fetch("/v1/localize?format=ply", { method: "POST", body: spectraForm() }).then((r) => r.arrayBuffer()),
    session ? identified(session) : fetch(`/v1/retrieve?top=${RETRIEVED}`, { method: "POST", body: spectraForm() }).then(answer),
    fetch("/v1/reconstruct?format=ply", { method: "POST", body: spectraForm() }),
    session ? fetch(`/v1/sessions/${session.id}/body`) : null,
  ]);
  await showMeasurements(body);
  plot(session ?? region); // a session's union carries its own σ
  document.body.dataset.unionBy = session ? session.union_by : "";
  covered.show(ply);
  showCoverage(region);
  showWarnings([...(session?.warnings ?? []), ...region.warnings]);
  $("located").textContent = region.located_by === "correspondence"
    ? "Coverage from where each scan's vertices lie on the template (correspondence)."
    : "Coverage read from the union's spectrum: the region may be the mirror image of the scanned one.";
  document.body.dataset.located = region.located_by;
  showMatches(found);
  await showRebuilt(rebuilt);
  document.body.dataset.parts = String(parts.length); // what the browser test waits for
  setStatus(`${parts.length} part${parts.length > 1 ? "s" : ""}; union covers ${(100 * region.area_fraction).toFixed(1)} % of the body${openNote(region)}.`);
}

// A registered session's person, as the stored people nearest the body fitted to its scans, in the
// shape /v1/retrieve answers (one match per person); a session no body fits says why instead.
async function identified(current) {
  const response = await fetch(`/v1/sessions/${current.id}/identity?top=${SHOWN}`);
  if (response.status === 409) {
    return { ranked_by: "fitted_body", matches: [], warnings: [(await response.json()).detail] };
  }
  const found = await answer(response);
  const matches = found.people.map((person) => ({ label: person.label, distance: person.distance, share: null }));
  return { ranked_by: found.ranked_by, matches, warnings: found.warnings };
}

// Covering the template is not being closed: scans of the whole body still leave holes (the
// soles, the top of the head) unless they are capped, and the union's spectrum is then an open
// surface's (λ₁ > 0), which the identity search and the rebuilt body read that way.
function openNote(region) {
  if (region.area_fraction < 0.95 || region.eigenvalues[0] < OPEN_LAMBDA) return "";
  return `, yet its spectrum is an open surface's (λ₁ = ${region.eigenvalues[0].toFixed(2)}): the holes the scans leave, such as the soles, stay open unless "whole-body scans" caps them`;
}

// Every warning the union routes return (a unit slip, operands far apart in size), in one list.
function showWarnings(warnings) {
  $("warnings").replaceChildren(
    ...warnings.map((warning) => Object.assign(document.createElement("li"), { className: "warning", textContent: warning })),
  );
}

function plot(union) {
  const svg = $("plot");
  const [width, height, left, bottom] = [520, 300, 44, 24];
  const k = union.eigenvalues.length;
  const top = Math.max(...union.upper, ...parts.flatMap((part) => part.eigenvalues));
  const x = (i) => left + ((width - left - 10) * i) / (k - 1);
  const y = (value) => height - bottom - ((height - bottom - 10) * value) / top;
  const line = (values) => values.map((value, i) => `${x(i).toFixed(1)},${y(value).toFixed(1)}`).join(" ");
  const shape = (tag, attributes) => {
    const element = document.createElementNS(SVG, tag);
    for (const [name, value] of Object.entries(attributes)) element.setAttribute(name, value);
    return element;
  };
  const reversed = union.lower.map((value, i) => `${x(i).toFixed(1)},${y(value).toFixed(1)}`).reverse().join(" ");
  const label = (attributes, text) => Object.assign(shape("text", attributes), { textContent: text });
  const yTicks = [0, top / 2, top].map((value) => [
    shape("line", { class: "tick", x1: left - 4, y1: y(value), x2: left, y2: y(value) }),
    label({ class: "tick-label", x: left - 6, y: y(value) + 4, "text-anchor": "end" }, value.toPrecision(3)),
  ]);
  const xTicks = [0, Math.floor((k - 1) / 2), k - 1].map((i) => [
    shape("line", { class: "tick", x1: x(i), y1: height - bottom, x2: x(i), y2: height - bottom + 4 }),
    label({ class: "tick-label", x: x(i), y: height - bottom + 15, "text-anchor": "middle" }, `λ${i + 1}`),
  ]);
  const legend = [
    ["part", "each part"],
    ["union", "their union"],
  ].map(([kind, text], row) => [
    shape("line", { class: kind, x1: left + 12, y1: 18 + 14 * row, x2: left + 34, y2: 18 + 14 * row }),
    label({ x: left + 40, y: 22 + 14 * row }, text),
  ]);
  svg.replaceChildren(
    shape("line", { class: "axis", x1: left, y1: height - bottom, x2: width - 10, y2: height - bottom }),
    shape("line", { class: "axis", x1: left, y1: 10, x2: left, y2: height - bottom }),
    ...yTicks.flat(),
    ...xTicks.flat(),
    shape("polygon", { class: "band", points: `${line(union.upper)} ${reversed}` }),
    ...parts.map((part) => shape("polyline", { class: "part", points: line(part.eigenvalues) })),
    shape("polyline", { class: "union", points: line(union.eigenvalues) }),
    ...legend.flat(),
    shape("rect", { class: "band", x: left + 12, y: 43, width: 22, height: 8 }),
    label({ x: left + 40, y: 50 }, "90 % band of the union"),
  );
}

// A mesh viewer on one canvas: the first mesh frames the camera, later ones replace it in place.
function viewer(canvas, material) {
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xf4f4f4);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x888888, 2.2));
  const light = new THREE.DirectionalLight(0xffffff, 1.2);
  light.position.set(1, 2, 3);
  scene.add(light);
  const camera = new THREE.PerspectiveCamera(35, canvas.width / canvas.height, 0.01, 100);
  camera.up.set(0, 0, 1); // bodies stand along +z; OrbitControls fixes its orbit axis from camera.up when made
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.addEventListener("change", () => renderer.render(scene, camera));
  let mesh = null;
  return {
    show(buffer) {
      const geometry = new PLYLoader().parse(buffer);
      geometry.computeVertexNormals();
      if (mesh) {
        scene.remove(mesh);
        mesh.geometry.dispose();
      } else {
        geometry.computeBoundingSphere();
        const { center, radius } = geometry.boundingSphere;
        controls.target.copy(center);
        camera.position.set(center.x, center.y - 3.2 * radius, center.z);
        controls.update();
      }
      mesh = new THREE.Mesh(geometry, material);
      scene.add(mesh);
      renderer.render(scene, camera);
    },
    clear() {
      if (mesh) {
        scene.remove(mesh);
        mesh.geometry.dispose();
        mesh = null;
      }
      renderer.render(scene, camera);
    },
  };
}

const covered = viewer($("body"), new THREE.MeshLambertMaterial({ vertexColors: true }));
const rebuiltView = viewer($("rebuilt"), new THREE.MeshLambertMaterial({ color: 0xc8a07a }));

async function showRebuilt(response) {
  if (response.status === 501) {
    $("rebuilt-note").textContent = "These models have no shape decoder.";
    return;
  }
  if (!response.ok) {
    $("rebuilt-note").textContent = (await answer(response).catch((error) => error)).message;
    return;
  }
  rebuiltView.show(await response.arrayBuffer());
  const height = Number(response.headers.get("x-height-m"));
  const gap = Number(response.headers.get("x-spectrum-relative-error"));
  const verdict = response.headers.get("x-round-trip"); // the service's judgement: closed, open or unseen
  const note = $("rebuilt-note");
  note.dataset.height = height.toFixed(4);
  note.dataset.roundTrip = verdict;
  note.textContent = `Height ${(100 * height).toFixed(1)} cm; its own spectrum is ${(100 * gap).toFixed(1)} % from the union's`
    + ({
      open: ", as an open surface's comes back (holes such as the soles, or parts not scanned yet): the body is rebuilt closed, a guess where the scans do not reach.",
      unseen: ": not a complete body's spectrum yet, do not trust this body.",
    }[verdict] ?? ".");
  note.classList.toggle("warning", verdict === "unseen");
}

function showCoverage(region) {
  const entries = Object.entries(region.part_coverage);
  const missing = entries.filter(([, share]) => share < 0.5).map(([name]) => name.replaceAll("_", " "));
  $("missing").textContent = missing.length ? `Still missing: ${missing.join(", ")}.` : "Every body part is covered.";
  $("coverage").replaceChildren(
    ...entries.map(([name, share]) => {
      const li = document.createElement("li");
      li.dataset.part = name;
      li.dataset.coverage = share.toFixed(4);
      li.textContent = `${name.replaceAll("_", " ")}: ${(100 * share).toFixed(0)} %`;
      return li;
    }),
  );
}

// The measurements of the body fitted to a registered session's scans, each with its 90 %
// interval, and those the scans do not support; scans solved one by one have no session to fit.
async function showMeasurements(response) {
  const note = $("measurements-note");
  if (response === null) {
    $("measurements").replaceChildren();
    note.textContent = "Measurements come from registered scans: the body is fitted to them in one frame.";
    return;
  }
  let body;
  try {
    body = await answer(response);
  } catch (error) {
    $("measurements").replaceChildren();
    note.textContent = error.message;
    return;
  }
  const centimetres = (metres) => (100 * metres).toFixed(1);
  $("measurements").replaceChildren(
    ...body.measurements.map((m) => {
      const li = document.createElement("li");
      li.textContent = `${m.name.replace("_", " ")}: ${centimetres(m.value_m)} cm (${centimetres(m.lower_m)}–${centimetres(m.upper_m)})`;
      li.dataset.name = m.name;
      li.dataset.value = String(m.value_m);
      return li;
    }),
  );
  const missing = Object.keys(body.not_measured).map((name) => name.replace("_", " "));
  note.textContent = missing.length ? `Not measured, the scans did not see enough for them: ${missing.join(", ")}.` : "";
}

function showMatches(found) {
  // How the service ranked (the union, or the body rebuilt from an open one) and what it means.
  const note = $("matches-note");
  note.dataset.rankedBy = found.ranked_by;
  const profiled = found.ranked_by === "share_profile"
    ? "Two scans whose overlap was not measured: each stored body is ranked under the overlap that explains it best."
    : "";
  note.textContent = [...found.warnings, profiled].filter(Boolean).join(" ");
  note.classList.toggle("warning", found.warnings.some((warning) => warning.includes("not an identification")));
  $("matches").replaceChildren(
    ...byIdentity(found.matches).map(({ match, stored }) => {
      const li = document.createElement("li");
      const share = match.share === null ? "" : `, overlap ${match.share.toFixed(1)}`;
      const poses = stored > 1 ? `, ${stored} of its stored shapes` : "";
      li.textContent = `${match.label} (distance ${match.distance.toFixed(3)}${share}${poses})`;
      return li;
    }),
  );
}

// The ranked shapes as people: the database stores a person in several poses, each a shape of
// its own; each label is listed once, where its nearest shape ranks, with how many of its shapes
// were among those ranked. At most SHOWN people.
function byIdentity(matches) {
  const people = new Map();
  for (const match of matches) {
    const seen = people.get(match.label);
    if (seen) seen.stored += 1;
    else people.set(match.label, { match, stored: 1 });
  }
  return [...people.values()].slice(0, SHOWN);
}

$("file").addEventListener("change", async (event) => {
  for (const file of event.target.files) await addScan(file);
  event.target.value = "";
});
$("drop").addEventListener("dragover", (event) => {
  event.preventDefault();
  $("drop").classList.add("over");
});
$("drop").addEventListener("dragleave", () => $("drop").classList.remove("over"));
$("drop").addEventListener("drop", async (event) => {
  event.preventDefault();
  $("drop").classList.remove("over");
  for (const file of event.dataTransfer.files) await addScan(file);
});
$("reset").addEventListener("click", () => location.reload());
