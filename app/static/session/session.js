// The scanning-session page: each dropped scan is solved once by POST /v1/spectrum; after
// that only spectra are sent. After every scan the page asks /v1/localize (JSON and the
// coloured template as PLY), /v1/retrieve and /v1/reconstruct (the rebuilt body as PLY, its
// height and spectrum check in headers) for the union of all parts so far. With "registered
// scans" (one scanner's views: one frame, one pose) each scan's footprint token comes back
// with its spectrum, POST /v1/overlap measures the new scan against the union so far's token,
// and every union is told those overlaps and boundary shares. With "whole-body scans" each scan's holes are capped
// before its solve (cap_holes=true): a whole body scanned standing is solved as the closed body.
import * as THREE from "three";
import { OrbitControls } from "/static/vendor/three/OrbitControls.js";
import { PLYLoader } from "/static/vendor/three/PLYLoader.js";

const parts = []; // {name, eigenvalues, warnings, overlap, boundary (registered scans after the first), region}
let unionFootprint = null; // registered scans: the footprint token of the union so far
const $ = (id) => document.getElementById(id);
const SVG = "http://www.w3.org/2000/svg";

function setStatus(text, problem = false) {
  $("status").textContent = text;
  $("status").classList.toggle("problem", problem);
}

// Every part's spectrum, and where each lies on the template when every part was placed there
// (its region token from /v1/correspondence): the union is then localized, and each step's
// overlap measured, on the template.
function spectraForm() {
  const form = new FormData();
  form.append("spectra", JSON.stringify(parts.map((part) => part.eigenvalues)));
  if (parts.every((part) => part.region)) form.append("regions", JSON.stringify(parts.map((part) => part.region)));
  return form;
}

// What the served models do (GET /v1/models): what the union operator can be told (a model set
// that reads no boundary share answers 422 to one, so the page sends only what the models read),
// and whether uploaded parts are placed on the template.
const served = fetch("/v1/models").then(answer);
const toldInputs = served.then((models) => new Set(models.told));

// The union routes' query: the overlaps and boundary shares measured so far (one per union
// step), when registered, each only if the models read it.
async function told(query = "") {
  const reads = await toldInputs;
  const params = new URLSearchParams(query);
  if ($("registered").checked && parts.length > 1) {
    for (const name of ["overlap", "boundary"]) {
      if (reads.has(name)) params.set(name, parts.slice(1).map((part) => part[name]).join(","));
    }
  }
  const text = params.toString();
  return text ? `?${text}` : "";
}

// A registered scan's overlap and boundary share with the union so far (undefined for the first
// scan), and the token of the union with it: asked before the scan joins, so a failure leaves the
// session as it was.
async function measured(footprint) {
  if (unionFootprint === null) return { overlap: undefined, boundary: undefined, union: footprint };
  const form = new FormData();
  form.append("footprints", JSON.stringify([unionFootprint, footprint]));
  const found = await answer(await fetch("/v1/overlap", { method: "POST", body: form }));
  return { overlap: found.overlaps[0], boundary: found.boundaries[0], union: found.union_footprint };
}

async function answer(response) {
  const body = response.headers.get("content-type")?.includes("json") ? await response.json() : null;
  if (!response.ok) {
    throw new Error(body ? `${body.title}: ${body.detail}` : `HTTP ${response.status}`);
  }
  return body;
}

async function addScan(file) {
  setStatus(`Solving ${file.name}…`);
  const form = new FormData();
  form.append("file", file, file.name);
  const registered = $("registered").checked;
  try {
    const whole = $("whole").checked;
    // A partial scan is placed on the template (one solve gives its spectrum and its region);
    // registered scans are measured by their footprints, whole-body scans capped.
    const placed = (await served).correspondence && !registered && !whole;
    const query = `units=${$("units").value}${registered ? "&footprint=true" : ""}${whole ? "&cap_holes=true" : ""}`;
    const route = placed ? "/v1/correspondence" : "/v1/spectrum";
    const report = await answer(await fetch(`${route}?${query}`, { method: "POST", body: form }));
    const { overlap, boundary, union } = registered ? await measured(report.footprint) : {};
    const region = placed ? report.region.token : undefined;
    parts.push({ name: file.name, eigenvalues: report.eigenvalues, warnings: report.warnings, overlap, boundary, region });
    if (registered) unionFootprint = union;
    $("registered").disabled = true; // one kind of session: every scan registered, or none
    await refresh();
  } catch (error) {
    setStatus(`${file.name}: ${error.message}`, true);
  }
}

async function refresh() {
  const item = (part) => {
    const li = document.createElement("li");
    li.textContent = `${part.name}: λ₁ = ${part.eigenvalues[0].toFixed(3)}`;
    if (part.overlap !== undefined) {
      li.dataset.overlap = part.overlap.toFixed(4);
      li.dataset.boundary = part.boundary.toFixed(4);
      li.textContent += `; ${(100 * part.overlap).toFixed(0)} % inside the scans before, `;
      li.textContent += `${(100 * part.boundary).toFixed(0)} % of both edges left open (measured)`;
    }
    for (const warning of part.warnings) {
      const note = document.createElement("span");
      note.className = "warning";
      note.textContent = ` — ${warning}`;
      li.append(note);
    }
    return li;
  };
  $("parts").replaceChildren(...parts.map(item));
  setStatus(`Uniting ${parts.length} part${parts.length > 1 ? "s" : ""}…`);
  const [region, ply, found, rebuilt] = await Promise.all([
    fetch(`/v1/localize${await told()}`, { method: "POST", body: spectraForm() }).then(answer),
    fetch(`/v1/localize${await told("format=ply")}`, { method: "POST", body: spectraForm() }).then((r) => r.arrayBuffer()),
    fetch(`/v1/retrieve${await told("top=5")}`, { method: "POST", body: spectraForm() }).then(answer),
    fetch(`/v1/reconstruct${await told("format=ply")}`, { method: "POST", body: spectraForm() }),
  ]);
  plot(region);
  covered.show(ply);
  showCoverage(region);
  $("located").textContent = region.located_by === "correspondence"
    ? "Coverage from where each scan's vertices lie on the template (correspondence)."
    : "Coverage read from the union's spectrum: the region may be the mirror image of the scanned one.";
  document.body.dataset.located = region.located_by;
  showMatches(found);
  await showRebuilt(rebuilt);
  document.body.dataset.parts = String(parts.length); // what the browser test waits for
  setStatus(`${parts.length} part${parts.length > 1 ? "s" : ""}; union covers ${(100 * region.area_fraction).toFixed(1)} % of the body.`);
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
  svg.replaceChildren(
    shape("line", { class: "axis", x1: left, y1: height - bottom, x2: width - 10, y2: height - bottom }),
    shape("line", { class: "axis", x1: left, y1: 10, x2: left, y2: height - bottom }),
    Object.assign(shape("text", { x: 4, y: 16 }), { textContent: top.toFixed(0) }),
    Object.assign(shape("text", { x: 4, y: height - bottom }), { textContent: "0" }),
    Object.assign(shape("text", { x: width - 60, y: height - 6 }), { textContent: `i = 1…${k}` }),
    shape("polygon", { class: "band", points: `${line(union.upper)} ${reversed}` }),
    ...parts.map((part) => shape("polyline", { class: "part", points: line(part.eigenvalues) })),
    shape("polyline", { class: "union", points: line(union.eigenvalues) }),
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
    ...found.matches.map((match) => {
      const li = document.createElement("li");
      const share = match.share === null ? "" : `, overlap ${match.share.toFixed(1)}`;
      li.textContent = `${match.label} (distance ${match.distance.toFixed(3)}${share})`;
      return li;
    }),
  );
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
