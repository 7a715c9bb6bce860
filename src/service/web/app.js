// The meshsmooth web page. It uses only the public API:
//   GET  /v1/params/schema          the parameter form
//   POST /v1/jobs?format=glb        the upload (multipart: mesh + params)
//   GET  /v1/jobs/{id}/events       progress (server-sent events)
//   DELETE /v1/jobs/{id}            cancel
//   GET  /v1/jobs/{id}/mesh         the result (GLB for the view; ?format= for downloads)
//   GET  /v1/jobs/{id}/report       the quality report
// State for tests and scripts: <body data-state="ready|uploading|running|done|error|cancelled">.

import * as THREE from '/web/vendor/three.min.js';
import { parseGlb } from '/web/glb.js';

const $ = (id) => document.getElementById(id);
const STAGES = ['analyse', 'initial', 'label', 'adaptive', 'quality', 'report'];
const LABELS = [
  { name: 'flat', colour: [0.75, 0.75, 0.72] },
  { name: 'minimal', colour: [0.55, 0.35, 0.75] },
  { name: 'convex', colour: [0.90, 0.45, 0.15] },
  { name: 'concave', colour: [0.15, 0.50, 0.85] },
];
// Parameters the page sets itself: per-vertex results colour the view.
const PAGE_PARAMS = new Set(['vertex_results']);

let schema = null;
let current = null; // { id, events, before } of the job on screen
let started = 0; // performance.now() when the upload started
let reportInverted = null; // the report's final inverted_faces, once known

function setState(state) {
  document.body.dataset.state = state;
}

function status(text) {
  $('status').textContent = text;
}

function showError(text) {
  const box = $('error');
  box.textContent = text;
  box.hidden = false;
}

// ---------------------------------------------------------------- form

function resolve(node) {
  if (!node) return {};
  if (node.$ref) {
    const name = node.$ref.replace('#/$defs/', '');
    return { ...resolve(schema.$defs?.[name]), ...withoutKeys(node, ['$ref']) };
  }
  if (Array.isArray(node.allOf) && node.allOf.length === 1) {
    return { ...resolve(node.allOf[0]), ...withoutKeys(node, ['allOf']) };
  }
  if (Array.isArray(node.oneOf)) {
    const options = node.oneOf.map(resolve);
    const values = options.flatMap((o) => o.enum ?? (o.const !== undefined ? [o.const] : []));
    if (values.length === options.length) return { ...withoutKeys(node, ['oneOf']), enum: values };
  }
  return node;
}

function withoutKeys(node, keys) {
  return Object.fromEntries(Object.entries(node).filter(([k]) => !keys.includes(k)));
}

function types(node) {
  return Array.isArray(node.type) ? node.type : [node.type];
}

function fieldId(path) {
  return `p-${path.replaceAll('.', '-').replaceAll('_', '-')}`;
}

/** Adds the inputs of object schema `node` (defaults `defaults`) to `parent`. */
function buildFields(parent, node, defaults, prefix) {
  for (const [key, raw] of Object.entries(node.properties ?? {})) {
    const path = prefix ? `${prefix}.${key}` : key;
    if (PAGE_PARAMS.has(path)) continue;
    const prop = resolve(raw);
    const def = defaults?.[key] ?? prop.default;
    if (prop.properties) {
      const set = document.createElement('fieldset');
      const legend = document.createElement('legend');
      legend.textContent = key;
      set.append(legend);
      if (prop.description) set.append(help(prop.description));
      buildFields(set, prop, def, path);
      parent.append(set);
      continue;
    }
    parent.append(buildField(path, key, prop, def));
  }
}

function help(text) {
  const p = document.createElement('p');
  p.className = 'help';
  p.textContent = text;
  return p;
}

function buildField(path, key, prop, def) {
  const row = document.createElement('div');
  row.className = 'field';
  const id = fieldId(path);
  const label = document.createElement('label');
  label.htmlFor = id;
  label.textContent = key;
  let input;
  const t = types(prop);
  const nullable = t.includes('null');
  if (prop.enum) {
    input = document.createElement('select');
    for (const v of prop.enum) input.append(new Option(String(v), JSON.stringify(v)));
    input.value = JSON.stringify(def);
  } else if (t.includes('boolean') && nullable) {
    input = document.createElement('select');
    input.append(new Option('default of the format', 'null'), new Option('true', 'true'), new Option('false', 'false'));
    input.value = JSON.stringify(def ?? null);
  } else if (t.includes('boolean')) {
    input = document.createElement('input');
    input.type = 'checkbox';
    input.checked = Boolean(def);
  } else if (t.includes('integer') || t.includes('number')) {
    input = document.createElement('input');
    input.type = 'number';
    input.step = t.includes('integer') ? '1' : 'any';
    if (prop.minimum !== undefined) input.min = prop.minimum;
    if (prop.maximum !== undefined) input.max = prop.maximum;
    input.value = def ?? '';
    if (nullable) input.placeholder = 'none';
  } else {
    input = document.createElement('input');
    input.type = 'text';
    input.value = def ?? '';
  }
  input.id = id;
  input.dataset.path = path;
  input.dataset.default = JSON.stringify(def ?? null);
  input.dataset.kind = prop.enum || (t.includes('boolean') && nullable) ? 'json'
    : t.includes('boolean') ? 'bool'
      : t.includes('integer') || t.includes('number') ? 'number' : 'text';
  const err = document.createElement('span');
  err.className = 'field-error';
  err.id = `${id}-error`;
  err.setAttribute('aria-live', 'polite');
  input.setAttribute('aria-describedby', `${id}-help ${id}-error`);
  const description = prop.description ?? '';
  const text = help(/\bDefault\b/.test(description) ? description
    : `${description} Default: ${JSON.stringify(def ?? null)}.`);
  text.id = `${id}-help`;
  row.append(label, input, err, text);
  return row;
}

function inputValue(input) {
  switch (input.dataset.kind) {
    case 'bool': return input.checked;
    case 'json': return JSON.parse(input.value);
    case 'number': return input.value === '' ? null : Number(input.value);
    default: return input.value;
  }
}

/** The parameters that differ from their defaults, as a nested object. */
function collectParams() {
  const params = {};
  for (const input of $('params').querySelectorAll('[data-path]')) {
    const value = inputValue(input);
    if (JSON.stringify(value) === input.dataset.default) continue;
    const keys = input.dataset.path.split('.');
    let at = params;
    for (const k of keys.slice(0, -1)) at = at[k] ??= {};
    at[keys.at(-1)] = value;
  }
  return params;
}

function clearFieldErrors() {
  for (const e of document.querySelectorAll('.field-error')) e.textContent = '';
}

// ---------------------------------------------------------------- API calls

/** A readable message for a refused request, shown beside the parameter
 * at fault when the problem names one. */
async function problemMessage(response) {
  let p = {};
  try {
    p = await response.json();
  } catch {
    p = { detail: response.statusText };
  }
  const why = {
    413: 'The upload is too large',
    415: 'This is not a mesh format the service reads',
    422: 'The mesh or the parameters cannot be used',
    503: 'The service is busy',
  }[response.status] ?? 'The request was refused';
  let text = `${why} (${response.status} ${p.code ?? ''}): ${p.detail ?? ''}`;
  const retry = response.headers.get('Retry-After');
  if (retry) text += ` Retry in ${retry} s.`;
  if (p.field) {
    const err = document.getElementById(`${fieldId(p.field)}-error`);
    if (err) {
      err.textContent = p.detail;
      $('params-box').open = true;
    }
  }
  return text;
}

function submit(file, params) {
  const form = new FormData();
  form.append('mesh', file, file.name);
  form.append('params', new Blob([JSON.stringify(params)], { type: 'application/json' }));
  return fetch('/v1/jobs?format=glb', { method: 'POST', body: form });
}

/** Follows a job's events until it is final; `onState` sees every state. */
function follow(job, onState) {
  return new Promise((resolveFinal) => {
    const events = new EventSource(job.links.events);
    if (current && current.id === job.id) current.events = events;
    events.addEventListener('state', (e) => {
      const view = JSON.parse(e.data);
      onState(view);
      if (['succeeded', 'failed', 'cancelled'].includes(view.state)) {
        events.close();
        resolveFinal(view);
      }
    });
  });
}

async function fetchMesh(job) {
  const r = await fetch(`${job.links.mesh}?format=glb`);
  if (!r.ok) throw new Error(await problemMessage(r));
  return parseGlb(await r.arrayBuffer());
}

// ---------------------------------------------------------------- flow

async function start(file) {
  if (current?.events) current.events.close();
  if (current?.before) fetch(`/v1/jobs/${current.before}`, { method: 'DELETE' });
  current = null;
  clearFieldErrors();
  $('error').hidden = true;
  $('downloads').hidden = true;
  $('summary').replaceChildren();
  clearHistogram();
  reportInverted = null;
  view.clear();
  setState('uploading');
  started = performance.now();
  delete document.body.dataset.uploadToRenderMs;
  delete document.body.dataset.before;
  status(`Uploading ${file.name} (${(file.size / 1e6).toFixed(2)} MB)...`);
  const params = { ...collectParams(), vertex_results: true };
  let response;
  try {
    response = await submit(file, params);
  } catch (e) {
    return fail(`The upload failed: ${e.message}`);
  }
  if (!response.ok) return fail(await problemMessage(response));
  const job = await response.json();
  current = { id: job.id, events: null };
  $('cancel').disabled = false;
  setState('running');
  showBefore(file, params, job);
  const final = await follow(job, progress);
  if (current?.id !== job.id) return;
  $('cancel').disabled = true;
  if (final.state === 'cancelled') {
    setState('cancelled');
    status('Cancelled.');
    return;
  }
  if (final.state === 'failed') {
    const p = final.error ?? {};
    return fail(`The job failed (${p.code ?? 'error'}): ${p.detail ?? ''}`);
  }
  try {
    const [mesh, report] = await Promise.all([
      fetchMesh(final),
      fetch(final.links.report).then((r) => r.json()),
    ]);
    if (current?.id !== job.id) return;
    view.setMesh('after', mesh);
    view.render();
    document.body.dataset.uploadToRenderMs = String(Math.round(performance.now() - started));
    showReport(final, report);
    showDownloads(final);
    status(`Done: ${final.input.vertices} vertices, ${final.input.faces} faces, `
      + `${(final.run_seconds ?? 0).toFixed(2)} s on the server.`);
    setState('done');
  } catch (e) {
    fail(`The result could not be shown: ${e.message}`);
  }
}

/** The input as the service reads it (welded like the job's): the same
 * upload with zero smoothing iterations and no quality fixes, as GLB. */
async function showBefore(file, params, job) {
  const identity = {
    method: 'laplacian',
    baseline: { iterations: 0 },
    quality: { enabled: false },
    weld: params.weld ?? null,
  };
  if (params.weld_tolerance !== undefined) identity.weld_tolerance = params.weld_tolerance;
  try {
    const r = await submit(file, identity);
    if (!r.ok) {
      $('caption-before').textContent = `before: not available (${await problemMessage(r)})`;
      return;
    }
    const before = await r.json();
    if (current?.id === job.id) current.before = before.id;
    const final = await follow(before, () => {});
    if (final.state !== 'succeeded' || current?.id !== job.id) return;
    const mesh = await fetchMesh(final);
    await fetch(final.links.self, { method: 'DELETE' });
    if (current?.id !== job.id) return;
    delete current.before;
    view.setMesh('before', mesh);
    view.render();
    document.body.dataset.before = 'shown';
  } catch (e) {
    $('caption-before').textContent = `before: not available (${e.message})`;
  }
}

function fail(text) {
  setState('error');
  $('cancel').disabled = true;
  status('Refused or failed: see the message below.');
  showError(text);
}

function progress(v) {
  const list = $('stages');
  if (!list.children.length) {
    for (const s of STAGES) {
      const li = document.createElement('li');
      li.textContent = s;
      li.dataset.stage = s;
      list.append(li);
    }
  }
  const index = STAGES.indexOf(v.stage);
  for (const li of list.children) {
    const i = STAGES.indexOf(li.dataset.stage);
    li.className = v.state === 'succeeded' || (index >= 0 && i < index) ? 'done' : i === index ? 'active' : '';
  }
  if (v.state === 'queued') {
    status(`Queued (position ${v.queue_position ?? 0}).`);
  } else if (v.state === 'running') {
    const fraction = index >= 0 ? (index + (v.progress ?? 0)) / STAGES.length : 0;
    $('bar').value = fraction;
    status(`Running: ${v.stage ?? 'starting'} (${Math.round((v.progress ?? 0) * 100)}%)${v.cancel_requested ? ', cancelling' : ''}.`);
  } else if (v.state === 'succeeded') {
    $('bar').value = 1;
    status('Succeeded; fetching the result...');
  }
}

// ---------------------------------------------------------------- 3D view

const view = (() => {
  const canvas = $('canvas');
  // preserveDrawingBuffer: the pixels stay readable after a frame
  // (screenshots, "save image as", the end-to-end test). Multisampling
  // only on a GPU: a software renderer (SwiftShader, no GPU) takes about
  // twice as long per frame with it (docs/browser.md has the figures).
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: !softwareRenderer(), preserveDrawingBuffer: true });
  renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
  renderer.setScissorTest(true);
  const camera = new THREE.PerspectiveCamera(35, 2, 0.01, 1000);
  const controls = new THREE.OrbitControls(camera, canvas);
  controls.listenToKeyEvents(canvas);
  controls.addEventListener('change', () => render());
  const scenes = {};
  const meshes = {};
  const overlays = [];
  const lights = [];
  for (const side of ['before', 'after']) {
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0xf4f4f0);
    scene.add(new THREE.HemisphereLight(0xffffff, 0x445566, 1.2));
    // A head light: follows the camera (draw()).
    const light = new THREE.DirectionalLight(0xffffff, 1.8);
    scene.add(light, light.target);
    lights.push(light);
    scenes[side] = scene;
  }
  let pending = false;

  function layout() {
    const mode = $('layout').value;
    return mode === 'split' ? ['before', 'after'] : [mode];
  }

  function render() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      draw();
    });
  }

  function draw() {
    const width = canvas.clientWidth || canvas.width;
    const height = canvas.clientHeight || canvas.height;
    if (canvas.width !== Math.round(width * renderer.getPixelRatio())) renderer.setSize(width, height, false);
    const sides = layout();
    const w = width / sides.length;
    camera.aspect = w / height;
    camera.updateProjectionMatrix();
    for (const light of lights) {
      light.position.copy(camera.position).add(camera.up.clone().multiplyScalar(camera.position.distanceTo(controls.target) * 0.3));
      light.target.position.copy(controls.target);
    }
    sides.forEach((side, i) => {
      renderer.setViewport(i * w, 0, w, height);
      renderer.setScissor(i * w, 0, w, height);
      renderer.render(scenes[side], camera);
    });
    $('caption-before').hidden = !sides.includes('before');
    $('caption-after').hidden = !sides.includes('after');
  }

  function setMesh(side, data) {
    if (meshes[side]) {
      scenes[side].remove(meshes[side]);
      meshes[side].geometry.dispose();
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(data.positions, 3));
    geometry.setIndex(new THREE.BufferAttribute(data.indices, 1));
    geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(data.positions.length).fill(0.8), 3));
    geometry.computeBoundingSphere();
    const material = new THREE.MeshLambertMaterial({
      vertexColors: true, flatShading: true, side: THREE.DoubleSide, wireframe: $('wireframe').checked,
    });
    const mesh = new THREE.Mesh(geometry, material);
    mesh.userData.results = data.results;
    meshes[side] = mesh;
    scenes[side].add(mesh);
    if (side === 'after' || !meshes.after) frame(geometry.boundingSphere);
    recolour();
    markFlipped();
  }

  /** Highlights, on both sides, the triangles whose normal turned more
   * than 90° from the input's: the folds. Before and after share vertex
   * order and triangles, so this is a per-triangle comparison. */
  function markFlipped() {
    for (const o of overlays.splice(0)) {
      o.parent?.remove(o);
      o.geometry.dispose();
    }
    const info = $('flipped');
    if (!meshes.before || !meshes.after) {
      info.textContent = '';
      delete info.dataset.count;
      return;
    }
    const a = meshes.before.geometry;
    const b = meshes.after.geometry;
    const idx = b.index.array;
    if (a.index.array.length !== idx.length || a.attributes.position.count !== b.attributes.position.count) {
      info.textContent = 'Flipped faces: before and after differ in size; not compared.';
      return;
    }
    const pa = a.attributes.position.array;
    const pb = b.attributes.position.array;
    const flipped = [];
    for (let t = 0; t < idx.length; t += 3) {
      if (dotOfNormals(pa, pb, idx[t], idx[t + 1], idx[t + 2]) < 0) flipped.push(idx[t], idx[t + 1], idx[t + 2]);
    }
    info.dataset.count = String(flipped.length / 3);
    info.textContent = `${flipped.length / 3} triangles flipped relative to the input`
      + (flipped.length ? ' (red)' : '') + (reportInverted === null ? '' : `; the report counts ${reportInverted} inverted faces.`);
    if (!flipped.length || !$('show-flipped').checked) return render();
    for (const side of ['before', 'after']) {
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', meshes[side].geometry.attributes.position);
      g.setIndex(new THREE.BufferAttribute(Uint32Array.from(flipped), 1));
      const m = new THREE.Mesh(g, new THREE.MeshBasicMaterial({
        color: 0xe00000, side: THREE.DoubleSide, polygonOffset: true, polygonOffsetFactor: -2, polygonOffsetUnits: -2,
      }));
      scenes[side].add(m);
      overlays.push(m);
    }
    render();
  }

  function frame(sphere) {
    const r = sphere.radius || 1;
    controls.target.copy(sphere.center);
    camera.near = r / 100;
    camera.far = r * 100;
    camera.position.copy(sphere.center).add(new THREE.Vector3(0.6, 0.5, 1).normalize().multiplyScalar(r * 4.2));
    camera.updateProjectionMatrix();
    controls.saveState();
    controls.update();
  }

  /** Colours both meshes by the result's per-vertex attribute (the two
   * share vertex order); returns the legend to show. */
  function recolour() {
    const mode = $('colour').value;
    const results = meshes.after?.userData.results ?? {};
    const legend = $('legend');
    legend.replaceChildren();
    let colourOf = null;
    if (mode === 'label' && results._LABEL) {
      const counts = [0, 0, 0, 0];
      for (const l of results._LABEL) counts[l] = (counts[l] ?? 0) + 1;
      LABELS.forEach((l, i) => legend.append(swatch(l.colour, `${l.name} (${counts[i]})`)));
      colourOf = (i, out) => out.set(LABELS[results._LABEL[i]]?.colour ?? [0, 0, 0]);
    } else if (mode === 'mean_curvature' && results._MEAN_CURVATURE) {
      const h = results._MEAN_CURVATURE;
      const range = percentile(h.map(Math.abs), 0.98) || 1;
      legend.append(ramp(`mean curvature H: ${(-range).toPrecision(3)}`, `${range.toPrecision(3)} (1/length)`, diverging));
      colourOf = (i, out) => out.set(diverging(h[i] / range));
    } else if (mode === 'displacement' && results._DISPLACEMENT) {
      const d = results._DISPLACEMENT;
      const max = d.reduce((m, x) => Math.max(m, x), 0) || 1;
      legend.append(ramp('displacement: 0', `${max.toPrecision(3)} (length)`, (t) => sequential((t + 1) / 2)));
      colourOf = (i, out) => out.set(sequential(d[i] / max));
    } else if (mode !== 'none') {
      legend.textContent = 'The result has no such per-vertex attribute.';
    }
    const rgb = new Float32Array(3);
    for (const mesh of Object.values(meshes)) {
      const colours = mesh.geometry.getAttribute('color');
      const n = colours.count;
      const sameOrder = (results._LABEL ?? results._DISPLACEMENT ?? { length: n }).length === n;
      for (let i = 0; i < n; i++) {
        if (colourOf && sameOrder) colourOf(i, rgb);
        else rgb.set([0.8, 0.8, 0.78]);
        colours.setXYZ(i, rgb[0], rgb[1], rgb[2]);
      }
      colours.needsUpdate = true;
    }
    render();
  }

  function setWireframe(on) {
    for (const mesh of Object.values(meshes)) mesh.material.wireframe = on;
    render();
  }

  function clear() {
    for (const side of Object.keys(meshes)) {
      scenes[side].remove(meshes[side]);
      meshes[side].geometry.dispose();
      delete meshes[side];
    }
    $('legend').replaceChildren();
    markFlipped();
  }

  canvas.addEventListener('keydown', (e) => {
    if (e.key === '+' || e.key === '-') {
      const scale = e.key === '+' ? 0.8 : 1.25;
      camera.position.sub(controls.target).multiplyScalar(scale).add(controls.target);
      controls.update();
      e.preventDefault();
    } else if (e.key === 'r') {
      controls.reset();
    }
  });
  window.addEventListener('resize', render);
  $('layout').addEventListener('change', render);
  $('colour').addEventListener('change', recolour);
  $('wireframe').addEventListener('change', (e) => setWireframe(e.target.checked));
  $('reset-view').addEventListener('click', () => controls.reset());
  $('show-flipped').addEventListener('change', markFlipped);
  return { setMesh, render, clear, markFlipped };
})();

/** Whether WebGL runs on a software rasteriser (no GPU). */
function softwareRenderer() {
  const gl = document.createElement('canvas').getContext('webgl2');
  const info = gl?.getExtension('WEBGL_debug_renderer_info');
  const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : '';
  gl?.getExtension('WEBGL_lose_context')?.loseContext();
  return /swiftshader|llvmpipe|software/i.test(name);
}

/** Dot product of the normals of triangle (i, j, k) in positions `a` and `b`. */
function dotOfNormals(a, b, i, j, k) {
  const n = (p) => {
    const ux = p[3 * j] - p[3 * i], uy = p[3 * j + 1] - p[3 * i + 1], uz = p[3 * j + 2] - p[3 * i + 2];
    const vx = p[3 * k] - p[3 * i], vy = p[3 * k + 1] - p[3 * i + 1], vz = p[3 * k + 2] - p[3 * i + 2];
    return [uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx];
  };
  const x = n(a);
  const y = n(b);
  return x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
}

function percentile(values, q) {
  const sorted = Float32Array.from(values).sort();
  return sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] ?? 0;
}

/** Blue (negative) - white - red (positive), `t` in [-1, 1]. */
function diverging(t) {
  const x = Math.max(-1, Math.min(1, t));
  return x < 0 ? [1 + x * 0.85, 1 + x * 0.6, 1] : [1, 1 - x * 0.6, 1 - x * 0.85];
}

/** Dark blue - green - yellow, `t` in [0, 1]. */
function sequential(t) {
  const x = Math.max(0, Math.min(1, t));
  return [Math.min(1, x * 1.8) * 0.95, 0.15 + 0.8 * x, 0.45 * (1 - x) + 0.1];
}

function swatch(colour, text) {
  const item = document.createElement('span');
  item.className = 'swatch';
  const box = document.createElement('i');
  box.style.background = `rgb(${colour.map((c) => Math.round(c * 255)).join(',')})`;
  item.append(box, document.createTextNode(text));
  return item;
}

function ramp(left, right, colour) {
  const item = document.createElement('span');
  item.className = 'ramp';
  const bar = document.createElement('i');
  const stops = [-1, -0.5, 0, 0.5, 1].map((t) => `rgb(${colour(t).map((c) => Math.round(c * 255)).join(',')})`);
  bar.style.background = `linear-gradient(to right, ${stops.join(',')})`;
  item.append(document.createTextNode(left), bar, document.createTextNode(right));
  return item;
}

// ---------------------------------------------------------------- report

function clearHistogram() {
  const c = $('histogram');
  c.getContext('2d').clearRect(0, 0, c.width, c.height);
  delete c.dataset.drawn;
}

function drawHistogram(input, result) {
  const c = $('histogram');
  const g = c.getContext('2d');
  const pad = { l: 56, r: 24, t: 24, b: 28 };
  const w = c.width - pad.l - pad.r;
  const h = c.height - pad.t - pad.b;
  const bins = input.length;
  const max = Math.max(1, ...input, ...result);
  g.clearRect(0, 0, c.width, c.height);
  g.fillStyle = '#fff';
  g.fillRect(0, 0, c.width, c.height);
  const series = [[input, '#9aa4b1', 'input'], [result, '#d0612a', 'result']];
  series.forEach(([counts, colour], s) => {
    g.fillStyle = colour;
    counts.forEach((n, i) => {
      const bh = (n / max) * h;
      g.fillRect(pad.l + (i + s / 2) * (w / bins), pad.t + h - bh, w / bins / 2 - 1, bh);
    });
  });
  g.strokeStyle = '#333';
  g.beginPath();
  g.moveTo(pad.l, pad.t);
  g.lineTo(pad.l, pad.t + h);
  g.lineTo(pad.l + w, pad.t + h);
  g.stroke();
  g.fillStyle = '#333';
  g.font = '12px sans-serif';
  for (let deg = 0; deg <= 180; deg += 30) g.fillText(`${deg}°`, pad.l + (deg / 180) * w - 8, pad.t + h + 16);
  g.fillText(String(max), 2, pad.t + 4);
  series.forEach(([, colour, name], s) => {
    g.fillStyle = colour;
    g.fillRect(pad.l + 10 + s * 90, 6, 12, 12);
    g.fillStyle = '#333';
    g.fillText(name, pad.l + 26 + s * 90, 16);
  });
  c.dataset.drawn = '1';
}

function fmt(x, digits = 4) {
  if (x === null || x === undefined) return '–';
  return typeof x === 'number' ? Number(x.toPrecision(digits)).toString() : String(x);
}

function table(headers, rows) {
  const t = document.createElement('table');
  const head = t.createTHead().insertRow();
  for (const h of headers) {
    const th = document.createElement('th');
    th.textContent = h;
    head.append(th);
  }
  const body = t.createTBody();
  for (const row of rows) {
    const tr = body.insertRow();
    for (const cell of row) tr.insertCell().textContent = cell;
  }
  return t;
}

function heading(text) {
  const h = document.createElement('h3');
  h.textContent = text;
  return h;
}

function showReport(job, report) {
  const stages = report.stages ?? {};
  reportInverted = stages.final?.inverted_faces ?? null;
  view.markFlipped();
  const input = stages.input?.triangle_angles?.histogram ?? [];
  const result = stages.final?.triangle_angles?.histogram ?? [];
  drawHistogram(input, result);
  const out = $('summary');
  out.replaceChildren();
  if (report.warnings?.length) {
    const list = document.createElement('ul');
    list.className = 'warnings';
    for (const w of report.warnings) {
      const li = document.createElement('li');
      li.textContent = w;
      list.append(li);
    }
    out.append(heading('Warnings'), list);
  }
  const names = ['input', 'initial', 'adaptive', 'final'].filter((s) => stages[s]);
  out.append(heading(`Stages (${report.reproducibility?.method ?? job.params.method})`), table(
    ['stage', 'curvature variation', 'mean edge', 'min angle', 'max angle', 'inverted faces', 'twisted quads', 'volume change', 'mean displacement', 'max displacement'],
    names.map((s) => {
      const m = stages[s];
      return [s, fmt(m.curvature_variation?.mean), fmt(m.mean_edge_length), fmt(m.triangle_angles?.min_deg),
        fmt(m.triangle_angles?.max_deg), fmt(m.inverted_faces), fmt(m.twisted_quads),
        m.volume?.relative_change === undefined || m.volume?.relative_change === null ? '–' : `${fmt(m.volume.relative_change * 100, 3)} %`,
        fmt(m.displacement?.mean), fmt(m.displacement?.max)];
    }),
  ));
  if (report.wang_yu?.labels) {
    const l = report.wang_yu.labels;
    const pairs = report.wang_yu.paired_triangles
      ? `, ${report.wang_yu.paired_triangles} triangle pairs read as voxel faces` : '';
    const noise = report.wang_yu.input_noise === undefined || report.wang_yu.input_noise === null
      ? '' : `, input noise ${fmt(report.wang_yu.input_noise, 3)} mean edges`;
    const grid = report.wang_yu.input_grid ? ` (input grid: ${report.wang_yu.input_grid}${noise}${pairs})` : '';
    out.append(heading(`Labels${grid}`), table(Object.keys(l), [Object.values(l).map(String)]));
  }
  if (report.quality_fixes) {
    const q = report.quality_fixes;
    out.append(heading('Quality fixes'), table(['fix', 'found', 'remaining'], [
      ['twisted quads', q.twisted?.found, q.twisted?.remaining],
      ['short edges', q.short_edges?.found, q.short_edges?.remaining],
      ['sharp angles (faces)', q.sharp_angles?.faces_found, q.sharp_angles?.faces_remaining],
      ['inverted faces', q.inverted?.found, q.inverted?.remaining],
      ['slivers', q.slivers?.found, q.slivers?.remaining],
    ].map((r) => r.map((x) => fmt(x)))));
  }
  out.append(heading(`Timings (total ${fmt(report.total_ms)} ms)`), table(
    (report.timings ?? []).map((t) => t.stage),
    [(report.timings ?? []).map((t) => `${fmt(t.ms)} ms`)],
  ));
}

function showDownloads(job) {
  const select = $('mesh-format');
  if ([...select.options].some((o) => o.value === job.input.format)) select.value = job.input.format;
  const update = () => {
    $('download-mesh').href = `${job.links.mesh}?format=${select.value}`;
  };
  select.onchange = update;
  update();
  $('download-report').href = job.links.report;
  $('downloads').hidden = false;
}

// ---------------------------------------------------------------- set-up

async function init() {
  const [schemaResponse, samplesResponse] = await Promise.all([
    fetch('/v1/params/schema'), fetch('/web/samples.json'),
  ]);
  schema = await schemaResponse.json();
  buildFields($('params'), schema, null, '');
  for (const sample of await samplesResponse.json()) {
    const button = document.createElement('button');
    button.type = 'button';
    button.textContent = sample.file;
    button.title = `${sample.description}, ${(sample.bytes / 1024).toFixed(0)} KiB`;
    button.dataset.sample = sample.file;
    button.addEventListener('click', async () => {
      const blob = await (await fetch(sample.url)).blob();
      start(new File([blob], sample.file));
    });
    $('samples').append(button);
  }
  const input = $('file');
  input.addEventListener('change', () => {
    const file = input.files[0];
    // Cleared so that picking the same file again starts again.
    input.value = '';
    if (file) start(file);
  });
  const drop = $('drop');
  drop.addEventListener('dragover', (e) => {
    e.preventDefault();
    drop.classList.add('over');
  });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => {
    e.preventDefault();
    drop.classList.remove('over');
    if (e.dataTransfer.files.length) start(e.dataTransfer.files[0]);
  });
  $('cancel').addEventListener('click', async () => {
    if (!current) return;
    $('cancel').disabled = true;
    if (current.before) fetch(`/v1/jobs/${current.before}`, { method: 'DELETE' });
    const r = await fetch(`/v1/jobs/${current.id}`, { method: 'DELETE' });
    if (!r.ok && r.status !== 404) showError(await problemMessage(r));
  });
  view.render();
  setState('ready');
}

init().catch((e) => {
  setState('error');
  showError(`The page could not start: ${e.message}`);
});
