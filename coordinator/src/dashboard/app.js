// The farm's page: a snapshot of jobs and workers pushed by server-sent
// events, the selected job's frame and strips fetched as they change.
'use strict';

const $ = (s) => document.querySelector(s);
const palette = ['#2f6b3a', '#c0762b', '#3b6ea5', '#8f3b76', '#6b8f23', '#a33a3a', '#3a8f8a', '#6b5b3a'];
let selected = null;
let needsToken = false;
let lastStrips = -1;
let lastState = '';

function token() {
  return sessionStorage.getItem('sylva_token') || '';
}

function setToken(t) {
  sessionStorage.setItem('sylva_token', t);
  // EventSource and <img> cannot send headers: reading uses this cookie.
  document.cookie = 'sylva_token=' + encodeURIComponent(t) + '; path=/; SameSite=Strict';
  connect();
}

function seconds(from, to) {
  if (!from) return '–';
  return ((to - from) / 1000).toFixed(1) + ' s';
}

function text(tag, value, cls) {
  const el = document.createElement(tag);
  el.textContent = value;
  if (cls) el.className = cls;
  return el;
}

async function act(path, body) {
  const r = await fetch(path, {
    method: 'POST',
    headers: { 'Authorization': 'Bearer ' + token(), 'Content-Type': 'application/json' },
    body: body ? JSON.stringify(body) : '',
  });
  $('#message').textContent = r.ok ? '' : path + ': ' + (await r.text());
  return r.ok ? r.json() : null;
}

function left(ms) {
  const s = Math.ceil(ms / 1000);
  return s < 120 ? '~' + s + ' s left' : '~' + Math.ceil(s / 60) + ' min left';
}

// A link that downloads a finished job's frame (the cookie carries the token).
function download(id, format, frame, label) {
  const a = text('a', label);
  a.href = '/api/jobs/' + id + '/result/' + format + '?frame=' + frame;
  a.setAttribute('download', '');
  a.dataset.download = id + ':' + format + ':' + frame;
  a.onclick = (e) => e.stopPropagation();
  return a;
}

function renderJobs(snap) {
  const body = $('#jobs tbody');
  body.replaceChildren();
  const jobs = snap.jobs.slice().sort((a, b) => b.submitted_unix_ms - a.submitted_unix_ms);
  for (const j of jobs) {
    const tr = document.createElement('tr');
    tr.dataset.job = j.id;
    if (j.id === selected) tr.className = 'selected';
    const name = text('td', j.name, 'name');
    name.title = j.name;
    tr.append(text('td', j.id), name, text('td', j.state, 'state state-' + j.state));
    const prio = document.createElement('td');
    prio.append(text('span', j.priority + ' ', 'priority'));
    if (!j.ended) {
      for (const [label, d] of [['+', 1], ['−', -1]]) {
        const b = text('button', label);
        b.dataset.priority = j.id;
        b.dataset.delta = d;
        b.onclick = (e) => { e.stopPropagation(); act('/api/jobs/' + j.id + '/priority', { priority: j.priority + d }); };
        prio.append(b);
      }
    }
    const progress = document.createElement('td');
    const bar = document.createElement('progress');
    bar.max = Math.max(1, j.strips_total);
    bar.value = j.strips_done;
    const frames = j.frames > 1 ? ' · frames ' + j.frames_done + '/' + j.frames : '';
    progress.append(bar, text('span', ' ' + j.strips_done + '/' + j.strips_total + frames + (j.retries ? ' (' + j.retries + ' retried)' : '')));
    // What the farm is doing for it, and the time left once strips return.
    if (j.stage || j.eta_ms) {
      progress.append(text('div', [j.stage, j.eta_ms ? left(j.eta_ms) : ''].filter(Boolean).join(' · '), 'stage'));
    }
    const now = snap.now_unix_ms;
    const queuedEnd = j.started_unix_ms || j.finished_unix_ms || now;
    // Queued, then running: the time in each, as far as it got.
    const time = 'queued ' + seconds(j.submitted_unix_ms, queuedEnd) +
      (j.started_unix_ms ? ' · ran ' + seconds(j.started_unix_ms, j.finished_unix_ms || now) : '');
    tr.append(prio, progress, text('td', time), text('td', j.submitter), text('td', j.error, 'reason'));
    const actions = document.createElement('td');
    if (!j.ended) {
      const b = text('button', 'cancel');
      b.dataset.cancel = j.id;
      b.onclick = (e) => { e.stopPropagation(); act('/api/jobs/' + j.id + '/cancel'); };
      actions.append(b);
    }
    if (j.requeueable) {
      const b = text('button', 'requeue');
      b.dataset.requeue = j.id;
      b.onclick = async (e) => {
        e.stopPropagation();
        const r = await act('/api/jobs/' + j.id + '/requeue');
        if (r) { selected = r.id; lastStrips = -1; }
      };
      actions.append(b);
    }
    if (j.state === 'done' && j.frames <= 1) {
      actions.append(download(j.id, 'png', 0, 'PNG'), download(j.id, 'exr', 0, 'EXR'));
    }
    tr.append(actions);
    tr.onclick = () => { selected = j.id; lastStrips = -1; renderJobs(snap); refreshFrame(j); };
    body.append(tr);
  }
  if (!selected && jobs.length) selected = jobs[0].id;
  const current = jobs.find((j) => j.id === selected);
  if (current && (current.strips_done + current.retries !== lastStrips || current.state !== lastState)) refreshFrame(current);
}

function renderWorkers(snap) {
  const body = $('#workers tbody');
  body.replaceChildren();
  for (const w of snap.workers) {
    const tr = document.createElement('tr');
    tr.dataset.worker = w.addr;
    const traversal = text('td', (w.backend || '–') + (w.ray_queries ? ' (rq offered)' : ''));
    traversal.title = w.backend_why || '';
    tr.append(text('td', w.addr), text('td', w.adapter || '–'), traversal, text('td', w.alive ? 'yes' : 'no', w.alive ? '' : 'state-failed'),
      text('td', w.busy_strips), text('td', w.strips_done), text('td', w.strips_failed),
      text('td', w.cached_scenes.map((h) => h.slice(0, 12)).join(', ')));
    body.append(tr);
  }
}

function svg(tag, attrs) {
  const el = document.createElementNS('http://www.w3.org/2000/svg', tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  return el;
}

function bars(target, values, labelMax) {
  const w = 420, h = 140, n = values.length;
  target.setAttribute('viewBox', '0 0 ' + w + ' ' + h);
  target.replaceChildren();
  const max = Math.max(1e-9, ...values);
  values.forEach((v, i) => {
    const bh = (h - 16) * v / max;
    target.append(svg('rect', { x: i * w / n, y: h - 14 - bh, width: Math.max(1, w / n - 1), height: bh, fill: '#2f6b3a' }));
  });
  const t = svg('text', { x: 2, y: 10, 'font-size': 10, fill: '#60705f' });
  t.textContent = labelMax(Math.max(0, ...values));
  target.append(t);
}

async function refreshFrame(job) {
  lastStrips = job.strips_done + job.retries;
  lastState = job.state;
  $('#frame').hidden = false;
  $('#frame-id').textContent = job.id + ' (' + job.state + ')';
  // A finished job's frames to download, each as PNG and EXR.
  const links = [];
  if (job.state === 'done') {
    for (let f = 0; f < Math.max(1, job.frames); f++) {
      if (job.frames > 1) links.push(document.createTextNode('frame ' + f + ': '));
      links.push(download(job.id, 'png', f, 'PNG'), download(job.id, 'exr', f, 'EXR'));
    }
  }
  $('#downloads').replaceChildren(...links);
  if (job.state === 'queued') return;
  const r = await fetch('/api/jobs/' + job.id + '/live');
  if (!r.ok) return;
  const live = await r.json();
  if (job.state === 'running' || job.state === 'done') {
    $('#preview').src = '/api/jobs/' + job.id + '/preview.png?n=' + lastStrips + '&s=' + job.state;
  }
  // Which worker rendered which columns.
  const cols = $('#columns');
  cols.setAttribute('viewBox', '0 0 ' + Math.max(1, live.width) + ' 10');
  cols.setAttribute('preserveAspectRatio', 'none');
  cols.replaceChildren();
  const workers = [...new Set(live.strips.map((s) => s.worker))];
  for (const s of live.strips.filter((s) => !s.error)) {
    const c = palette[workers.indexOf(s.worker) % palette.length];
    const rect = svg('rect', { x: s.x0, y: 0, width: s.x1 - s.x0, height: 10, fill: c });
    rect.append(svg('title', {}));
    rect.firstChild.textContent = s.worker + ': columns ' + s.x0 + '–' + s.x1 + ', ' + s.ms.toFixed(0) + ' ms';
    cols.append(rect);
  }
  $('#legend').replaceChildren(...workers.map((w, i) => {
    const li = document.createElement('li');
    const sw = text('span', '', 'swatch');
    sw.style.background = palette[i % palette.length];
    li.append(sw, document.createTextNode(w + ': ' + live.strips.filter((s) => s.worker === w && !s.error).length + ' strips'));
    return li;
  }));
  $('#retries').replaceChildren(...live.strips.filter((s) => s.error).map((s) =>
    text('li', 'columns ' + s.x0 + '–' + s.x1 + ' failed on ' + s.worker + ': ' + s.error)));
  // Strip-latency histogram and the frame's per-column cost.
  const ms = live.strips.filter((s) => !s.error).map((s) => s.ms);
  const bins = new Array(16).fill(0);
  const top = Math.max(1, ...ms);
  for (const v of ms) bins[Math.min(15, Math.floor(16 * v / top))]++;
  bars($('#latency'), bins, (m) => m + ' strips; bins to ' + top.toFixed(0) + ' ms');
  const n = Math.min(120, live.column_ms.length);
  const per = live.column_ms.length / Math.max(1, n);
  const cost = Array.from({ length: n }, (_, i) => {
    const part = live.column_ms.slice(Math.floor(i * per), Math.floor((i + 1) * per));
    return part.reduce((a, b) => a + b, 0) / Math.max(1, part.length);
  });
  bars($('#cost'), cost, (m) => m.toFixed(2) + ' ms per column at most');
}

let source = null;
function connect() {
  if (source) source.close();
  source = new EventSource('/api/events');
  source.addEventListener('snapshot', (e) => {
    const snap = JSON.parse(e.data);
    needsToken = snap.needs_token;
    $('#token-box').hidden = !needsToken;
    $('#connection').textContent = 'live';
    // A database that refuses writes is the operator's first concern.
    $('#store').hidden = !snap.store_problem;
    $('#store').textContent = snap.store_problem ? 'store unhealthy' : '';
    $('#store').title = snap.store_problem || '';
    renderJobs(snap);
    renderWorkers(snap);
  });
  source.onerror = () => {
    $('#connection').textContent = needsToken || !token() ? 'disconnected (token?)' : 'reconnecting…';
    $('#token-box').hidden = false;
  };
}

$('#token').value = token();
$('#token').addEventListener('change', (e) => setToken(e.target.value));
connect();
