// Bayesian Fields web page: plain JS over the JSON API. The API key lives in this browser's
// localStorage for this site (until "log out") and goes out as X-API-Key on every call, so the API's
// own auth and tenant isolation apply. Kept per browser, not per tab, so a link to a job or batch
// page (/ui/jobs/ID, /ui/batches/ID) opens signed in; the key itself never goes into a URL.
"use strict";
const KEY = "bfields-api-key";
const POLL_MS = 1500;
const key = () => localStorage.getItem(KEY);
const jobPage = (id) => `/ui/jobs/${encodeURIComponent(id)}`;
const batchPage = (id) => `/ui/batches/${encodeURIComponent(id)}`;

// The id a job or batch page is for: /ui/jobs/ID, /ui/batches/ID, or the older /ui/job?id=ID form.
function pageId() {
  const m = location.pathname.match(/^\/ui\/(?:jobs|batches)\/([^/]+)$/);
  return m ? decodeURIComponent(m[1]) : new URLSearchParams(location.search).get("id") || "";
}

// No key (or one the API no longer accepts) on a job or batch page: to the sign-in form, which
// comes back here after signing in.
function signInFirst() {
  localStorage.removeItem(KEY);
  location.replace(`/ui/?next=${encodeURIComponent(location.pathname + location.search)}`);
}

// Where the sign-in form goes on: a /ui page named by ?next= (same site only), else nowhere.
function nextPage() {
  const next = new URLSearchParams(location.search).get("next") || "";
  return /^\/ui\/[^/\\]/.test(next) ? next : null;
}

async function api(path, opts = {}) {
  const headers = Object.assign({ "X-API-Key": key() || "" }, opts.headers || {});
  const resp = await fetch(path, Object.assign({}, opts, { headers }));
  const text = await resp.text();
  let body = null;
  try { body = text ? JSON.parse(text) : null; } catch (e) { body = text; }
  if (resp.status === 401 && document.body.dataset.page !== "index") signInFirst();
  if (!resp.ok) throw new Error((body && body.detail) ? (typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail)) : `HTTP ${resp.status}`);
  return body;
}

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else if (k === "text") node.textContent = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
}
const $ = (id) => document.getElementById(id);
const bar = (p) => el("span", { class: "bar" }, el("span", { style: `width:${Math.round(p)}%` }));
const when = (t) => (t ? new Date(t).toLocaleTimeString() : "");
const tasksOf = (text) => text.split("\n").map((s) => s.trim()).filter(Boolean);
const timings = (t) => Object.entries(t || {}).map(([k, v]) => `${k} ${Number(v).toFixed(1)}`).join(", ");

// An artifact's bytes as an object URL: API-served links need the key header; presigned ones not.
async function artifactUrl(url) {
  if (!url.startsWith("/")) return url;
  const resp = await fetch(url, { headers: { "X-API-Key": key() } });
  if (!resp.ok) throw new Error(`HTTP ${resp.status} for ${url}`);
  return URL.createObjectURL(await resp.blob());
}

// ---- index: login, upload, scenes, jobs --------------------------------------------------
async function initIndex() {
  const showApp = (on) => {
    $("login-section").classList.toggle("hidden", on);
    $("app").classList.toggle("hidden", !on);
    $("logout").classList.toggle("hidden", !on);
    $("who").textContent = on ? "signed in with an API key" : "";
  };
  $("login-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    localStorage.setItem(KEY, $("api-key").value.trim());
    try { await api("/v1/jobs?limit=1"); } catch (e) { localStorage.removeItem(KEY); $("login-error").textContent = e.message; return; }
    $("login-error").textContent = "";
    if (nextPage()) { location.replace(nextPage()); return; }
    showApp(true); refresh();
  });
  $("logout").addEventListener("click", (ev) => { ev.preventDefault(); localStorage.removeItem(KEY); showApp(false); });
  if (key() && nextPage()) { location.replace(nextPage()); return; }
  $("upload-form").addEventListener("submit", upload);
  $("submit-job").addEventListener("click", () => submitJobs(false));
  $("submit-batch").addEventListener("click", () => submitJobs(true));
  if (key()) { showApp(true); refresh(); }
  setInterval(() => { if (key()) refreshJobs().catch(() => {}); }, POLL_MS);
}

// The stage column: a running job's stage; a finished job's outcome ("done", "failed in fuse"),
// never its last stage as if it were still at it (a succeeded job said "stage: cluster").
const FINISHED = ["succeeded", "failed", "cancelled"];
function stageText(j) {
  if (j.state === "succeeded") return "done";
  if (FINISHED.includes(j.state)) return j.stage ? `${j.state} in ${j.stage}` : j.state;
  return j.stage || "";
}

async function refresh() { await Promise.all([refreshScenes(), refreshJobs()]); }

async function refreshScenes() {
  const body = await api("/v1/scenes?limit=100");
  const rows = $("scenes").tBodies[0];
  rows.replaceChildren(...body.items.map((s) => el("tr", { "data-scene": s.id },
    el("td", {}, el("input", { type: "checkbox", class: "pick", value: s.id })),
    el("td", { text: s.id }), el("td", { text: s.name || "" }),
    el("td", { text: String((s.summary || {}).gaussians ?? "") }), el("td", { text: String((s.summary || {}).frames ?? "") }),
    el("td", { text: when(s.created_at) }))));
}

async function refreshJobs() {
  const body = await api("/v1/jobs?limit=50");
  const rows = $("jobs").tBodies[0];
  rows.replaceChildren(...body.items.map((j) => el("tr", { "data-job": j.id, "data-state": j.state },
    el("td", {}, el("a", { href: jobPage(j.id), text: j.id })),
    el("td", { text: j.scene_id }), el("td", { text: j.tasks.join("; ") }),
    el("td", { class: `state-${j.state}`, text: j.state }), el("td", { text: stageText(j) }),
    el("td", {}, bar(j.state === "succeeded" ? 100 : j.progress), ` ${Math.round(j.progress)}%`),
    el("td", { text: when(j.updated_at) }))));
  $("jobs-updated").textContent = `(updated ${new Date().toLocaleTimeString()})`;
}

async function upload(ev) {
  ev.preventDefault();
  const status = $("upload-status");
  const form = new FormData();
  form.append("name", $("scene-name").value);
  form.append("splat", $("splat").files[0]);
  for (const f of $("cameras").files) form.append("cameras", f);
  for (const f of $("images").files) form.append("images", f);
  if ($("transform").files.length) form.append("transform", $("transform").files[0]);
  status.textContent = "uploading...";
  try {
    const scene = await api("/v1/scenes", { method: "POST", body: form });
    status.textContent = `scene ${scene.id} ready (${scene.summary.gaussians} Gaussians, ${scene.summary.frames} frames)`;
    const tasks = tasksOf($("upload-tasks").value);
    if (tasks.length) {
      const job = await api("/v1/jobs", { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ scene_id: scene.id, tasks }) });
      status.textContent += `; job ${job.id} submitted`;
    }
    await refresh();
  } catch (e) { status.textContent = ""; status.append(el("span", { class: "error", text: e.message })); }
}

async function submitJobs(asBatch) {
  const status = $("submit-status");
  const scenes = [...document.querySelectorAll("input.pick:checked")].map((c) => c.value);
  const tasks = tasksOf($("job-tasks").value);
  if (!scenes.length || !tasks.length) { status.textContent = "tick at least one scene and give tasks"; return; }
  const json = { "Content-Type": "application/json" };
  try {
    if (asBatch) {
      const b = await api("/v1/batches", { method: "POST", headers: json, body: JSON.stringify({ scene_ids: scenes, task_lists: [tasks] }) });
      status.textContent = "";
      $("batches").append(el("div", {}, "batch ", el("a", { href: batchPage(b.id), text: b.id }), ` (${b.jobs.length} jobs)`));
    } else {
      for (const s of scenes) await api("/v1/jobs", { method: "POST", headers: json, body: JSON.stringify({ scene_id: s, tasks }) });
      status.textContent = `${scenes.length} job(s) submitted`;
    }
    await refreshJobs();
  } catch (e) { status.textContent = ""; status.append(el("span", { class: "error", text: e.message })); }
}

// ---- job page: live status, previews, downloads -------------------------------------------
async function initJob() {
  const id = pageId();
  $("job-id").textContent = id;
  if (!key()) { signInFirst(); return; }
  let shown = false;
  const tick = async () => {
    let job;
    try { job = await api(`/v1/jobs/${encodeURIComponent(id)}`); }
    catch (e) { $("job-error").textContent = e.message; return; }
    $("job-state").textContent = job.state; $("job-state").className = `state-${job.state}`;
    document.body.dataset.state = job.state;
    $("job-stage").textContent = stageText(job);
    const p = job.state === "succeeded" ? 100 : job.progress;
    $("job-bar").style.width = `${p}%`; $("job-progress").textContent = `${Math.round(p)}%`;
    $("job-tasks").textContent = job.tasks.join("; ");
    $("job-timings").textContent = timings(job.timings);
    $("job-error").textContent = job.error || "";
    if (job.state === "succeeded" && !shown) { shown = true; await showResult(id); }
    if (!FINISHED.includes(job.state)) setTimeout(tick, POLL_MS);
  };
  tick();
}

// A file of the job saved under `name`: fetched with the key, handed to the browser as a download.
async function saveAs(url, name) {
  const tmp = el("a", { href: await artifactUrl(url), download: name });
  document.body.append(tmp); tmp.click(); tmp.remove();
}

function fileLink(a, text) {
  const link = el("a", { href: "#", "data-path": a.path, text });
  link.addEventListener("click", (ev) => { ev.preventDefault(); saveAs(a.url, a.path.split("/").pop()); });
  return link;
}

const xyz = (v, digits) => (v ? `(${v.map((c) => Number(c).toFixed(digits)).join(", ")})` : "");

// One table per task from summary.json's selections: rank, object, p, Gaussians, box, its file.
function objectTables(summary, byPath) {
  const cols = ["rank", "object", "p(relevant)", "Gaussians", "box centre", "box extents", "file"];
  return (summary.selections || []).map((sel) => {
    const table = el("table", { class: "objects", "data-task": sel.task },
      el("caption", { text: sel.task }), el("thead", {}, el("tr", {}, ...cols.map((c) => el("th", { text: c })))));
    const body = el("tbody");
    sel.objects.forEach((o, rank) => {
      const art = byPath[`result/${o.export}`];
      body.append(el("tr", { "data-object": o.object_id },
        el("td", { text: `#${rank + 1}` }), el("td", { text: `${o.object_id}` }),
        el("td", { text: Number(o.probability).toFixed(3) }), el("td", { text: `${o.num_gaussians}` }),
        el("td", { text: xyz(o.box && o.box.center, 3) }), el("td", { text: xyz(o.box && o.box.extents, 3) }),
        el("td", {}, art ? fileLink(art, o.export.split("/").pop()) : "")));
    });
    if (!sel.objects.length) {
      const why = sel.not_found ? `not found: ${sel.not_found.reason}` : "no object selected";
      body.append(el("tr", {}, el("td", { colspan: cols.length, class: "muted", text: why })));
    }
    table.append(body);
    return table;
  });
}

async function showResult(id) {
  const res = await api(`/v1/jobs/${encodeURIComponent(id)}/result`);
  const byPath = Object.fromEntries(res.artifacts.map((a) => [a.path, a]));
  const previews = (res.summary.previews || {}).tasks || [];
  const sheet = (res.summary.previews || {}).contact_sheet;
  const gallery = $("previews");
  for (const p of previews) {
    const art = byPath[`result/${p.file}`];
    if (!art) continue;
    const img = el("img", { alt: `preview: ${p.task}`, "data-task": p.task, width: p.width, height: p.height });
    gallery.append(el("figure", {}, img, el("figcaption", { text: p.task })));
    img.src = await artifactUrl(art.url);
  }
  $("objects").append(...objectTables(res.summary, byPath));
  $("download-all").addEventListener("click", () => saveAs(`/v1/jobs/${encodeURIComponent(id)}/result.zip`, `${id}.zip`));
  const rows = $("downloads").tBodies[0];
  for (const a of res.artifacts) {
    rows.append(el("tr", {}, el("td", {}, fileLink(a, a.path)), el("td", { text: `${a.size} bytes` })));
  }
  $("file-count").textContent = `${res.artifacts.length}`;
  if (sheet) document.body.dataset.contactSheet = sheet;
  $("result").classList.remove("hidden");
}

// ---- batch page: one row per scene, kept current by the batch's event stream ----------------
// Server-sent events read with fetch (EventSource cannot send the X-API-Key header): calls
// onEvent(name, data) per event until the server closes the stream.
async function readEvents(path, onEvent) {
  const resp = await fetch(path, { headers: { "X-API-Key": key() || "", Accept: "text/event-stream" } });
  if (!resp.ok || !resp.body) throw new Error(`HTTP ${resp.status} for ${path}`);
  const reader = resp.body.pipeThrough(new TextDecoderStream()).getReader();
  let buf = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buf += value;
    let cut;
    while ((cut = buf.indexOf("\n\n")) >= 0) {
      const block = buf.slice(0, cut);
      buf = buf.slice(cut + 2);
      let name = "message", data = "";
      for (const line of block.split("\n")) {
        if (line.startsWith("event: ")) name = line.slice(7); else if (line.startsWith("data: ")) data += line.slice(6);
      }
      if (data) onEvent(name, JSON.parse(data));
    }
  }
}

async function initBatch() {
  const id = pageId();
  $("batch-id").textContent = id;
  if (!key()) { signInFirst(); return; }
  const names = {};
  const rows = {};
  const summary = (c) => `${Math.round(c.progress)}% - ` + Object.entries(c.counts).map(([k, v]) => `${v} ${k}`).join(", ");
  // The batch's counts, then its jobs a page at a time (GET /v1/batches/{id} lists no jobs).
  const b = await api(`/v1/batches/${encodeURIComponent(id)}`);
  const jobs = [];
  for (let cursor = null; ;) {
    const page = await api(`/v1/batches/${encodeURIComponent(id)}/jobs?limit=500` + (cursor ? `&cursor=${cursor}` : ""));
    jobs.push(...page.items);
    if (!(cursor = page.next_cursor)) break;
  }
  for (const j of jobs) {
    if (!(j.scene_id in names)) {
      try { names[j.scene_id] = (await api(`/v1/scenes/${encodeURIComponent(j.scene_id)}`)).name || j.scene_id; }
      catch (e) { names[j.scene_id] = j.scene_id; }
    }
    const cells = { state: el("td"), stage: el("td"), progress: el("td"), timings: el("td"), thumb: el("td") };
    rows[j.id] = { tr: el("tr", { "data-job": j.id }, el("td", { text: names[j.scene_id] }),
      el("td", {}, el("a", { href: jobPage(j.id), text: j.id })),
      cells.state, cells.stage, cells.progress, cells.timings, cells.thumb), cells, state: null };
    show(j);
  }
  $("batch-jobs").tBodies[0].replaceChildren(...Object.values(rows).map((r) => r.tr));
  $("batch-summary").textContent = summary(b);

  // One job's row from an event (or the first snapshot); a finished job gets its timings and thumbnail.
  function show(j) {
    const row = rows[j.id];
    if (!row) return;
    const was = row.state;
    row.state = j.state;
    row.tr.dataset.state = j.state;
    row.cells.state.className = `state-${j.state}`;
    row.cells.state.textContent = j.state;
    row.cells.stage.textContent = stageText(j);
    row.cells.progress.replaceChildren(bar(j.state === "succeeded" ? 100 : j.progress));
    if (FINISHED.includes(j.state) && was !== j.state) finished(j.id, j.state).catch(() => {});
  }
  async function finished(jobId, state) {
    const detail = await api(`/v1/jobs/${encodeURIComponent(jobId)}`);
    rows[jobId].cells.timings.textContent = timings(detail.timings);
    if (state !== "succeeded") return;
    const res = await api(`/v1/jobs/${encodeURIComponent(jobId)}/result`);
    const sheet = (res.summary.previews || {}).contact_sheet;
    const art = res.artifacts.find((a) => a.path === `result/${sheet}`);
    if (art) rows[jobId].cells.thumb.replaceChildren(el("img", { class: "thumb", src: await artifactUrl(art.url), alt: `preview of ${jobId}` }));
  }

  showAnswers(id).catch((e) => { $("answers-summary").textContent = e.message; });

  let events = 0;
  document.body.dataset.stream = "open";
  const onEvent = (name, data) => {
    document.body.dataset.events = String(++events);
    if (name === "job") show(data);
    else if (name === "counts") { $("batch-summary").textContent = summary(data); document.body.dataset.finished = String(data.finished); }
    else if (name === "end") { document.body.dataset.stream = "ended"; showAnswers(id).catch(() => {}); }
  };
  // Reconnect until the batch ends (the server closes a stream after BFIELDS_EVENTS_MAX_S).
  while (document.body.dataset.stream !== "ended") {
    try { await readEvents(`/v1/batches/${encodeURIComponent(id)}/events`, onEvent); }
    catch (e) { $("batch-summary").textContent = e.message; await new Promise((r) => setTimeout(r, POLL_MS)); }
  }
}

// The batch's answers (GET /v1/batches/{id}/answers, each task's best object per job): per task,
// the scenes where it was found, most probable first, each with its preview linking to the job,
// and how many jobs answered it "not found".
async function showAnswers(id) {
  const rows = [];
  for (let cursor = null; ;) {
    const page = await api(`/v1/batches/${encodeURIComponent(id)}/answers?max_rank=1&limit=500` + (cursor ? `&cursor=${cursor}` : ""));
    rows.push(...page.items);
    if (!(cursor = page.next_cursor)) break;
  }
  // per task: each scene's best found answer (a scene asked twice shows once), and the scenes
  // where no job of the batch found it
  const tasks = new Map();
  for (const r of rows) {
    if (!tasks.has(r.task)) tasks.set(r.task, { best: new Map(), asked: new Set() });
    const t = tasks.get(r.task);
    t.asked.add(r.scene_id);
    const had = t.best.get(r.scene_id);
    if (r.found && (!had || r.probability > had.probability)) t.best.set(r.scene_id, r);
  }
  const blocks = [];
  for (const [task, t] of tasks) {
    t.found = [...t.best.values()].sort((a, b) => b.probability - a.probability);
    t.missing = t.asked.size - t.found.length;
    const body = t.found.map((r, i) => {
      const thumb = el("td");
      if (r.preview_url) {
        const img = el("img", { class: "thumb", alt: `preview: ${task} in ${r.scene_name || r.scene_id}` });
        thumb.append(el("a", { href: jobPage(r.job_id) }, img));
        artifactUrl(r.preview_url).then((u) => { img.src = u; }).catch(() => {});
      }
      return el("tr", { "data-job": r.job_id, "data-scene": r.scene_id },
        el("td", { text: `#${i + 1}` }), el("td", { text: r.scene_name || r.scene_id }),
        el("td", { text: r.probability.toFixed(3) }), el("td", { text: String(r.object_id) }),
        el("td", {}, el("a", { href: jobPage(r.job_id), text: r.job_id })), thumb);
    });
    const head = el("tr", {}, ...["rank", "scene", "p", "object", "job", "preview"].map((h) => el("th", { text: h })));
    blocks.push(el("table", { class: "objects answers", "data-task": task },
      el("caption", { text: `${task}: found in ${t.found.length} scene(s), not found in ${t.missing}` }),
      el("thead", {}, head), el("tbody", {}, ...body)));
  }
  $("answers").replaceChildren(...blocks);
  $("answers-summary").textContent = rows.length ? `${tasks.size} task(s)` : "none yet (answers appear as jobs succeed)";
  document.body.dataset.answers = String(rows.length);
}

document.addEventListener("DOMContentLoaded", () => {
  const page = document.body.dataset.page;
  if (page === "index") initIndex(); else if (page === "job") initJob(); else if (page === "batch") initBatch().catch((e) => { $("batch-summary").textContent = e.message; });
});
