// mbsim view: the mechanism of result files in 3D (three.js) with channel time histories.
// Data: the JSON in #mbsim-data, written by mbsim/view/page.py (arrays base64, little endian).
// URL fragment: #t=1.5&case=0&frames=1&follow=0&play=1&channels=bodies/crank/r,monitors/energy
// sets the time (and pauses), the case, body frames, following the heaviest body, playing,
// the plotted channels.
// window.mbsimView exposes setTime, setCase and the figures firstFrameMs, frameMs.
(function () {
  'use strict';
  const T = THREE;
  const DATA = JSON.parse(document.getElementById('mbsim-data').textContent);
  const $ = (id) => document.getElementById(id);
  const stats = { firstFrameMs: null, frameMs: null, frames: 0 };

  function bytes(b64) {
    const s = atob(b64), u = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) u[i] = s.charCodeAt(i);
    return u.buffer;
  }
  const f32 = (b) => new Float32Array(bytes(b));
  const f64 = (b) => new Float64Array(bytes(b));
  const u32 = (b) => new Uint32Array(bytes(b));
  const u8 = (b) => new Uint8Array(bytes(b));

  function hashParams() {
    const out = {};
    for (const part of location.hash.replace(/^#/, '').split('&')) {
      const i = part.indexOf('=');
      if (i > 0) out[decodeURIComponent(part.slice(0, i))] = decodeURIComponent(part.slice(i + 1));
    }
    return out;
  }
  const params = hashParams();

  // ---------------------------------------------------------------- renderer, camera, lights
  const box = $('view3d');
  const renderer = new T.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  box.appendChild(renderer.domElement);
  const scene = new T.Scene();
  scene.background = new T.Color(0xf4f5f7);
  const camera = new T.PerspectiveCamera(40, 1, 0.01, 1000);
  scene.add(camera);
  scene.add(new T.HemisphereLight(0xffffff, 0x667080, 1.6));
  const sun = new T.DirectionalLight(0xffffff, 1.8);
  sun.position.set(1, 2, 3);
  camera.add(sun);
  const controls = new T.OrbitControls(camera, renderer.domElement);
  controls.enableDamping = false;
  controls.addEventListener('change', () => requestDraw());

  // ---------------------------------------------------------------- state
  const state = { c: null, time: 0, playing: false, speed: 1, last: null, follow: null,
                  followPrev: null, size: 1, up: new T.Vector3(0, 1, 0), grid: null, level: 0 };
  let root = null; // THREE.Group of the current case

  function srgbToLinear(c) {
    c /= 255;
    return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
  }

  function bodyMesh(b) {
    const g = new T.BufferGeometry();
    g.setAttribute('position', new T.BufferAttribute(f32(b.v), 3));
    const c8 = u8(b.c), col = new Float32Array(c8.length);
    for (let i = 0; i < c8.length; i++) col[i] = srgbToLinear(c8[i]);
    g.setAttribute('color', new T.BufferAttribute(col, 3));
    g.setIndex(new T.BufferAttribute(u32(b.f), 1));
    g.computeVertexNormals();
    g.computeBoundingSphere();
    const m = new T.MeshStandardMaterial({ vertexColors: true, roughness: 0.55, metalness: 0.1,
                                           side: T.DoubleSide });
    return new T.Mesh(g, m);
  }

  function prepare(c) {
    // decode a case once; c.ready caches it
    if (c.ready) return c;
    c.time = f64(c.t);
    for (const b of c.bodies) { b.R = f32(b.r); b.Q = f32(b.p); }
    for (const ch of c.channels) {
      ch.k = ch.components.length;
      const raw = f32(ch.data), v = new Float64Array(raw.length);
      for (let i = 0; i < raw.length; i++) v[i] = raw[i] + ch.offset[i % ch.k];
      ch.values = v;
      let lo = Infinity, hi = -Infinity;
      for (const x of ch.values) { if (x < lo) lo = x; if (x > hi) hi = x; }
      ch.lo = lo; ch.hi = hi;
    }
    c.index = {};
    c.bodies.forEach((b, k) => { c.index[b.name] = k; });
    c.ready = true;
    return c;
  }

  const JOINT_COLOR = 0x222222, FORCE_COLOR = 0xd62728, SPRING_COLOR = 0xff7f0e;

  function build(c) {
    if (root) {
      scene.remove(root);
      root.traverse((o) => { if (o.geometry) o.geometry.dispose(); if (o.material) o.material.dispose(); });
    }
    root = new T.Group();
    scene.add(root);
    // size: the spread of the bodies and their shapes at the first output
    const lo = new T.Vector3(Infinity, Infinity, Infinity), hi = lo.clone().negate();
    c.nodes = c.bodies.map((b, k) => {
      const node = new T.Group();
      node.position.set(b.R[0], b.R[1], b.R[2]);
      lo.min(node.position); hi.max(node.position);
      if (b.v) {
        const mesh = bodyMesh(b);
        node.add(mesh);
        const s = mesh.geometry.boundingSphere;
        const ctr = s.center.clone().add(node.position);
        lo.min(ctr.clone().addScalar(-s.radius)); hi.max(ctr.clone().addScalar(s.radius));
      }
      root.add(node);
      return node;
    });
    state.size = Math.max(hi.clone().sub(lo).length(), 1e-3);
    state.center = lo.clone().add(hi).multiplyScalar(0.5);
    const s = state.size;
    // body frames (on demand)
    c.axes = c.nodes.map((node, k) => {
      const a = new T.AxesHelper(0.15 * s);
      a.visible = $('frames').checked;
      node.add(a);
      return a;
    });
    // joints, forces and output points: markers on the bodies, lines between bodies
    c.marks = new T.Group();
    root.add(c.marks);
    const dot = new T.SphereGeometry(0.012 * s, 12, 8);
    const mat = (color) => new T.MeshStandardMaterial({ color: color, roughness: 0.4 });
    const jointMat = mat(JOINT_COLOR), forceMat = mat(FORCE_COLOR), springMat = mat(SPRING_COLOR);
    const pointMat = mat(0x1f77b4);
    c.links = []; // [body i, P_i, body j, P_j] drawn as one line segment each
    const lay = c.layout || {};
    function marker(body, P, material, scale) {
      const k = c.index[body];
      if (k === undefined) return;
      const m = new T.Mesh(dot, material);
      m.position.set(P[0], P[1], P[2]);
      if (scale) m.scale.setScalar(scale);
      c.nodes[k].add(m);
      c.marksOnBodies = (c.marksOnBodies || []).concat([m]);
    }
    function axisLine(body, P, Q) {
      const k = c.index[body];
      if (k === undefined || !Q) return;
      const u = new T.Vector3(Q[0] - P[0], Q[1] - P[1], Q[2] - P[2]);
      if (u.length() < 1e-12) return;
      u.normalize().multiplyScalar(0.06 * s);
      const g = new T.BufferGeometry().setFromPoints([
        new T.Vector3(P[0], P[1], P[2]).sub(u), new T.Vector3(P[0], P[1], P[2]).add(u)]);
      const l = new T.LineSegments(g, new T.LineBasicMaterial({ color: JOINT_COLOR }));
      c.nodes[k].add(l);
      c.marksOnBodies = (c.marksOnBodies || []).concat([l]);
    }
    const AXIS_JOINTS = ['revolute', 'cylindrical', 'translational', 'universal', 'strut',
                         'revolute-spherical', 'revolute-cylindrical'];
    for (const j of lay.joints || []) {
      j.bodies.forEach((b, i) => {
        const ps = j.points[i];
        marker(b, ps.P, jointMat);
        if (AXIS_JOINTS.includes(j.type) && i === 0) axisLine(b, ps.P, ps.Q);
      });
      if (j.bodies.length === 2) c.links.push([j.bodies[0], j.points[0].P, j.bodies[1], j.points[1].P, 0]);
    }
    // force elements with a drawing of their own (mbsim/view/glyphs.py): primitives on bodies
    const glyphMats = {};
    function glyphMat(g) {
      const key = g.color + '/' + g.opacity;
      if (!glyphMats[key]) {
        const m = new T.MeshStandardMaterial({ color: new T.Color(g.color), roughness: 0.5,
                                               side: T.DoubleSide });
        if (g.opacity < 1) { m.transparent = true; m.opacity = g.opacity; m.depthWrite = false; }
        glyphMats[key] = m;
      }
      return glyphMats[key];
    }
    const vec = (a) => new T.Vector3(a[0], a[1], a[2]);
    function polyhedron(g) { // flat-shaded quads (g.faces) of g.corners (body frame)
      const pos = [];
      for (const [a, b, c2, d] of g.faces) for (const k of [a, b, c2, a, c2, d]) pos.push(...g.corners[k]);
      const geo = new T.BufferGeometry();
      geo.setAttribute('position', new T.Float32BufferAttribute(pos, 3));
      geo.computeVertexNormals();
      return new T.Mesh(geo, glyphMat(g));
    }
    const GLYPHS = { // one per primitive of mbsim/view/glyphs.py
      sphere: (g) => {
        const m = new T.Mesh(new T.SphereGeometry(g.radius, 24, 16), glyphMat(g));
        m.position.copy(vec(g.center));
        return m;
      },
      square: polyhedron,
      box: polyhedron,
      marker: (g) => {
        const m = new T.Mesh(dot, glyphMat(g));
        m.position.copy(vec(g.point));
        m.scale.setScalar(1.3);
        return m;
      },
      segment: (g) => new T.Line(new T.BufferGeometry().setFromPoints([vec(g.a), vec(g.b)]),
                                 new T.LineBasicMaterial({ color: new T.Color(g.color) })),
    };
    c.glyphs = [];
    function glyph(g) {
      const k = c.index[g.body], make = GLYPHS[g.shape];
      if (k === undefined || !make) return;
      const obj = make(g);
      c.nodes[k].add(obj);
      c.glyphs.push(obj);
      c.marksOnBodies = (c.marksOnBodies || []).concat([obj]);
    }
    for (const f of lay.forces || []) {
      if (f.glyphs) {
        f.glyphs.forEach(glyph);
      } else if (f.bodies.length === 2 && f.points.length === 2) {
        f.bodies.forEach((b, i) => marker(b, f.points[i].P, springMat));
        c.links.push([f.bodies[0], f.points[0].P, f.bodies[1], f.points[1].P, 1]);
      } else {
        f.bodies.forEach((b, i) => marker(b, f.points[i] ? f.points[i].P : [0, 0, 0], forceMat, 1.3));
      }
    }
    document.body.dataset.glyphs = String(c.glyphs.length); // for the tests (dump_dom)
    for (const p of lay.points || []) marker(p.body, p.point, pointMat, 0.8);
    c.linkPos = [new Float32Array(6 * c.links.length), new Float32Array(6 * c.links.length)];
    c.linkLines = [0, 1].map((kind) => {
      const g = new T.BufferGeometry();
      g.setAttribute('position', new T.BufferAttribute(c.linkPos[kind], 3));
      const l = new T.LineSegments(g, new T.LineBasicMaterial({ color: kind ? SPRING_COLOR : JOINT_COLOR }));
      l.frustumCulled = false;
      c.marks.add(l);
      return l;
    });
    setMarks($('marks').checked);
    // up: against gravity (y when there is none); ground grid under the mechanism
    const g = c.gravity || [0, 0, 0];
    const gv = new T.Vector3(-g[0], -g[1], -g[2]);
    state.up = gv.length() > 0 ? gv.normalize() : new T.Vector3(0, 1, 0);
    camera.up.copy(state.up);
    let level = Infinity;
    c.nodes.forEach((node, k) => {
      const b = c.bodies[k];
      if (!b.v) { level = Math.min(level, node.position.dot(state.up)); return; }
      const v = f32(b.v), q = new T.Quaternion(b.Q[1], b.Q[2], b.Q[3], b.Q[0]), x = new T.Vector3();
      for (let i = 0; i < v.length; i += 3) {
        x.set(v[i], v[i + 1], v[i + 2]).applyQuaternion(q).add(node.position);
        level = Math.min(level, x.dot(state.up));
      }
    });
    state.level = isFinite(level) ? level : 0;
    const cells = 20, cell = niceStep(s / 4);
    state.grid = new T.GridHelper(cells * cell, cells, 0xb0b4bc, 0xd4d7dd);
    state.grid.quaternion.setFromUnitVectors(new T.Vector3(0, 1, 0), state.up);
    state.cell = cell;
    root.add(state.grid);
    // follow the heaviest body when the mechanism travels far (a vehicle)
    let heavy = -1, mass = -1;
    c.bodies.forEach((b, k) => { if (!b.ground && (b.mass || 0) > mass) { mass = b.mass || 0; heavy = k; } });
    if (heavy < 0) heavy = c.bodies.findIndex((b) => !b.ground);
    state.follow = heavy;
    let travel = 0;
    if (heavy >= 0) {
      const R = c.bodies[heavy].R, n = c.nt - 1;
      travel = Math.hypot(R[3 * n] - R[0], R[3 * n + 1] - R[1], R[3 * n + 2] - R[2]);
    }
    $('follow').checked = travel > 2 * s;
    state.followPrev = null;
    resetCamera();
  }

  function niceStep(x) {
    const e = Math.pow(10, Math.floor(Math.log10(x))), m = x / e;
    return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * e;
  }

  function resetCamera() {
    const u = state.up, ref = Math.abs(u.x) < 0.9 ? new T.Vector3(1, 0, 0) : new T.Vector3(0, 0, 1);
    const e1 = ref.clone().sub(u.clone().multiplyScalar(ref.dot(u))).normalize();
    const e2 = new T.Vector3().crossVectors(u, e1);
    const target = state.c ? currentFollowPoint() || state.center : state.center;
    const dir = e1.multiplyScalar(0.8).add(e2.multiplyScalar(-1.3)).add(u.clone().multiplyScalar(0.7)).normalize();
    camera.near = state.size / 200; camera.far = state.size * 400;
    camera.updateProjectionMatrix();
    controls.target.copy(state.center);
    camera.position.copy(state.center).add(dir.multiplyScalar(1.6 * state.size));
    if (target !== state.center) {
      const d = target.clone().sub(state.center);
      controls.target.add(d); camera.position.add(d);
    }
    state.followPrev = currentFollowPoint();
    controls.update();
  }

  function currentFollowPoint() {
    const c = state.c;
    if (!c || state.follow < 0 || !c.nodes) return null;
    return c.nodes[state.follow].position.clone();
  }

  function setMarks(on) {
    const c = state.c || {};
    if (c.marks) c.marks.visible = on;
    for (const m of c.marksOnBodies || []) m.visible = on;
  }

  // ---------------------------------------------------------------- time
  function frameAt(time) {
    // (k, a): time lies between outputs k and k+1 at fraction a
    const t = state.c.time, n = t.length;
    if (n < 2 || time <= t[0]) return [0, 0];
    if (time >= t[n - 1]) return [n - 2, 1];
    let lo = 0, hi = n - 1;
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (t[mid] <= time) lo = mid; else hi = mid; }
    return [lo, (time - t[lo]) / (t[lo + 1] - t[lo])];
  }

  const qa = new T.Quaternion(), qb = new T.Quaternion(), va = new T.Vector3(), vb = new T.Vector3();
  function pose(b, k, a, pos, quat) {
    const R = b.R, Q = b.Q, k1 = Math.min(k + 1, state.c.nt - 1);
    pos.set(R[3 * k], R[3 * k + 1], R[3 * k + 2]);
    vb.set(R[3 * k1], R[3 * k1 + 1], R[3 * k1 + 2]);
    pos.lerp(vb, a);
    quat.set(Q[4 * k + 1], Q[4 * k + 2], Q[4 * k + 3], Q[4 * k]);
    qb.set(Q[4 * k1 + 1], Q[4 * k1 + 2], Q[4 * k1 + 3], Q[4 * k1]);
    quat.slerp(qb, a);
  }

  function place() {
    const c = state.c, [k, a] = frameAt(state.time);
    c.bodies.forEach((b, i) => pose(b, k, a, c.nodes[i].position, c.nodes[i].quaternion));
    // lines between bodies: P on each body in global coordinates
    const counts = [0, 0];
    for (const [bi, Pi, bj, Pj, kind] of c.links) {
      const ni = c.nodes[c.index[bi]], nj = c.nodes[c.index[bj]];
      if (!ni || !nj) continue;
      va.set(Pi[0], Pi[1], Pi[2]).applyQuaternion(ni.quaternion).add(ni.position);
      vb.set(Pj[0], Pj[1], Pj[2]).applyQuaternion(nj.quaternion).add(nj.position);
      const arr = c.linkPos[kind], o = 6 * counts[kind]++;
      arr[o] = va.x; arr[o + 1] = va.y; arr[o + 2] = va.z;
      arr[o + 3] = vb.x; arr[o + 4] = vb.y; arr[o + 5] = vb.z;
    }
    c.linkLines.forEach((l, kind) => {
      l.geometry.setDrawRange(0, 2 * counts[kind]);
      l.geometry.attributes.position.needsUpdate = true;
    });
    // follow: move the camera with the followed body; the grid stays under it, on its cells
    const p = currentFollowPoint();
    if (p && $('follow').checked && state.followPrev) {
      const d = p.clone().sub(state.followPrev);
      camera.position.add(d); controls.target.add(d);
    }
    state.followPrev = p;
    const ctr = controls.target.clone(), u = state.up;
    ctr.sub(u.clone().multiplyScalar(ctr.dot(u)));
    const cell = state.cell;
    ctr.set(Math.round(ctr.x / cell) * cell, Math.round(ctr.y / cell) * cell, Math.round(ctr.z / cell) * cell);
    ctr.sub(u.clone().multiplyScalar(ctr.dot(u))).add(u.clone().multiplyScalar(state.level));
    state.grid.position.copy(ctr);
    controls.update();
  }

  function duration() { const t = state.c.time; return t[t.length - 1] - t[0]; }

  function setTime(time) {
    const t = state.c.time;
    state.time = Math.min(Math.max(time, t[0]), t[t.length - 1]);
    const d = duration();
    $('slider').value = d > 0 ? Math.round(10000 * (state.time - t[0]) / d) : 0;
    $('clock').textContent = 't = ' + state.time.toFixed(d < 0.1 ? 5 : 3) + ' s';
    place();
    drawCursor();
    requestDraw();
  }

  let pending = false;
  function requestDraw() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(tick);
  }

  function render() {
    const t0 = performance.now();
    renderer.render(scene, camera);
    const ms = performance.now() - t0;
    stats.frames += 1;
    stats.frameMs = stats.frameMs === null ? ms : 0.9 * stats.frameMs + 0.1 * ms;
  }

  function tick(now) {
    pending = false;
    if (state.playing) {
      if (state.last !== null) {
        let time = state.time + (now - state.last) / 1000 * state.speed;
        const t = state.c.time;
        if (time > t[t.length - 1]) time = t[0]; // loop
        setTime(time);
      }
      state.last = now;
      pending = true;
      requestAnimationFrame(tick);
    }
    render();
  }

  function setPlaying(on) {
    state.playing = on;
    state.last = null;
    $('play').innerHTML = on ? '&#10074;&#10074;' : '&#9654;';
    requestDraw();
  }

  // ---------------------------------------------------------------- channel plot
  const plot = $('plot'), pctx = plot.getContext('2d');
  let plotBg = null, panels = [];
  const COLORS = ['#1f77b4', '#ff7f0e', '#2ca02c', '#d62728', '#9467bd', '#8c564b', '#e377c2',
                  '#7f7f7f', '#bcbd22', '#17becf'];

  function fmt(x) {
    if (x === 0) return '0';
    const a = Math.abs(x);
    return a >= 1e5 || a < 1e-3 ? x.toExponential(4) : String(+x.toPrecision(6));
  }

  function tickLabel(y, step) {
    // a tick label with the digits its step needs (0.15012, not 0.15)
    const big = Math.max(Math.abs(y), Math.abs(step));
    if (big >= 1e5 || big < 1e-4) return y.toExponential(Math.max(0, Math.min(8, Math.round(Math.log10(big / step)) + 1)));
    return y.toFixed(Math.max(0, Math.min(10, -Math.floor(Math.log10(step) + 1e-9))));
  }

  function selectedChannels() {
    const c = state.c;
    return Array.from($('channels').selectedOptions).map((o) => c.channels[+o.value]);
  }

  function drawPlot() {
    const c = state.c, w = plot.clientWidth, h = plot.clientHeight;
    const dpr = window.devicePixelRatio || 1;
    plot.width = Math.max(1, w * dpr); plot.height = Math.max(1, h * dpr);
    pctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    pctx.clearRect(0, 0, w, h);
    const chans = selectedChannels();
    const units = [];
    for (const ch of chans) if (!units.includes(ch.unit)) units.push(ch.unit);
    panels = [];
    const t = c.time, t0 = t[0], t1 = t[t.length - 1] > t0 ? t[t.length - 1] : t0 + 1;
    const L = 58, Rm = 8, ph = h / Math.max(units.length, 1);
    pctx.font = '11px system-ui, sans-serif';
    units.forEach((unit, ip) => {
      const top = ip * ph + 6, bot = (ip + 1) * ph - 20;
      const mine = chans.filter((ch) => ch.unit === unit);
      let lo = Math.min(...mine.map((ch) => ch.lo)), hi = Math.max(...mine.map((ch) => ch.hi));
      if (!(hi > lo)) { const d = Math.abs(lo) * 0.1 || 1; lo -= d; hi += d; }
      const pad = 0.05 * (hi - lo); lo -= pad; hi += pad;
      const X = (x) => L + (x - t0) / (t1 - t0) * (w - L - Rm), Y = (y) => bot - (y - lo) / (hi - lo) * (bot - top);
      panels.push({ X, Y, top, bot, mine });
      pctx.strokeStyle = '#ccc'; pctx.fillStyle = '#444'; pctx.lineWidth = 1;
      pctx.strokeRect(L, top, w - L - Rm, bot - top);
      const step = niceStep((hi - lo) / 4);
      pctx.textAlign = 'right'; pctx.textBaseline = 'middle';
      for (let y = Math.ceil(lo / step) * step; y <= hi; y += step) {
        pctx.fillText(tickLabel(y, step), L - 4, Y(y));
        pctx.beginPath(); pctx.moveTo(L, Y(y)); pctx.lineTo(L + 4, Y(y)); pctx.stroke();
      }
      pctx.save(); pctx.translate(10, (top + bot) / 2); pctx.rotate(-Math.PI / 2);
      pctx.textAlign = 'center'; pctx.fillText(unit ? '[' + unit + ']' : '[-]', 0, 0); pctx.restore();
      const tstep = niceStep((t1 - t0) / 5);
      pctx.textAlign = 'center'; pctx.textBaseline = 'top';
      for (let x = Math.ceil(t0 / tstep) * tstep; x <= t1 + 1e-9 * tstep; x += tstep) pctx.fillText(tickLabel(x, tstep), X(x), bot + 3);
      let color = 0, legendY = top + 4;
      for (const ch of mine) {
        for (let j = 0; j < ch.k; j++) {
          pctx.strokeStyle = COLORS[color % COLORS.length];
          pctx.beginPath();
          for (let i = 0; i < t.length; i++) {
            const x = X(t[i]), y = Y(ch.values[i * ch.k + j]);
            if (i) pctx.lineTo(x, y); else pctx.moveTo(x, y);
          }
          pctx.stroke();
          pctx.fillStyle = COLORS[color % COLORS.length]; pctx.textAlign = 'left'; pctx.textBaseline = 'top';
          pctx.fillText(ch.name.replace(/\//g, '.') + (ch.components[j] ? '.' + ch.components[j] : ''), L + 6, legendY);
          legendY += 13; color++;
        }
      }
    });
    if (!chans.length) { pctx.fillStyle = '#888'; pctx.fillText('choose channels above', L, 20); }
    plotBg = pctx.getImageData(0, 0, plot.width, plot.height);
    drawCursor();
  }

  function drawCursor() {
    if (!plotBg) return;
    pctx.putImageData(plotBg, 0, 0);
    const [k, a] = frameAt(state.time), lines = [];
    for (const p of panels) {
      const x = p.X(state.time);
      pctx.strokeStyle = '#d00'; pctx.lineWidth = 1;
      pctx.beginPath(); pctx.moveTo(x, p.top); pctx.lineTo(x, p.bot); pctx.stroke();
      for (const ch of p.mine) {
        const vals = [];
        for (let j = 0; j < ch.k; j++) {
          const k1 = Math.min(k + 1, state.c.nt - 1);
          const v = ch.values[k * ch.k + j] * (1 - a) + ch.values[k1 * ch.k + j] * a;
          vals.push((ch.components[j] ? ch.components[j] + ' ' : '') + fmt(v));
          pctx.fillStyle = '#d00'; pctx.beginPath(); pctx.arc(x, p.Y(v), 2.5, 0, 7); pctx.fill();
        }
        lines.push(ch.name.replace(/\//g, '.') + ' [' + (ch.unit || '-') + ']: ' + vals.join(', '));
      }
    }
    $('readout').textContent = lines.join('\n');
  }

  function fillChannels(c, wanted) {
    const sel = $('channels');
    sel.innerHTML = '';
    let group = null, groupName = null;
    c.channels.forEach((ch, i) => {
      const top = ch.name.split('/')[0];
      if (top !== groupName) { group = document.createElement('optgroup'); group.label = top; sel.appendChild(group); groupName = top; }
      const o = document.createElement('option');
      o.value = i; o.textContent = ch.name.replace(/\//g, '.') + (ch.unit ? ' [' + ch.unit + ']' : '');
      group.appendChild(o);
    });
    let pick = wanted ? c.channels.map((ch, i) => wanted.includes(ch.name) ? i : -1).filter((i) => i >= 0) : [];
    if (!pick.length) {
      const prefer = ['drivers/', 'measures/', 'forces/', 'monitors/energy'];
      for (const p of prefer) { const i = c.channels.findIndex((ch) => ch.name.startsWith(p)); if (i >= 0) { pick = [i]; break; } }
      if (!pick.length && state.follow >= 0) {
        const i = c.channels.findIndex((ch) => ch.name === 'bodies/' + c.bodies[state.follow].name + '/r');
        if (i >= 0) pick = [i];
      }
    }
    for (const o of sel.querySelectorAll('option')) o.selected = pick.includes(+o.value);
    $('side').style.display = c.channels.length ? '' : 'none';
  }

  // ---------------------------------------------------------------- cases, controls
  function setCase(i, wanted) {
    const c = prepare(DATA.cases[i]);
    state.c = c;
    build(c);
    const d = duration();
    const speeds = [0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10];
    const want = d < 2 ? d / 2 : 1; // a short run or a mode plays in about 2 s
    state.speed = speeds.reduce((a, b) => Math.abs(Math.log(b / want)) < Math.abs(Math.log(a / want)) ? b : a);
    const sp = $('speed');
    sp.innerHTML = '';
    for (const s of speeds) { const o = document.createElement('option'); o.value = s; o.textContent = s + 'x'; o.selected = s === state.speed; sp.appendChild(o); }
    const note = $('note');
    note.textContent = c.label + (c.status !== 'complete' ? '\nincomplete: ' + c.message : '');
    note.className = c.status !== 'complete' ? 'bad' : '';
    fillChannels(c, wanted);
    resize();
    setTime(c.time[0]);
  }

  function resize() {
    const w = box.clientWidth, h = box.clientHeight;
    renderer.setSize(w, h, true);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
    if (state.c) drawPlot();
    requestDraw();
  }

  $('play').onclick = () => setPlaying(!state.playing);
  $('slider').oninput = (e) => { const t = state.c.time; setTime(t[0] + e.target.value / 10000 * duration()); };
  $('speed').onchange = (e) => { state.speed = +e.target.value; };
  $('case').onchange = (e) => { setCase(+e.target.value, selectedChannels().map((ch) => ch.name)); };
  $('frames').onchange = (e) => { for (const a of state.c.axes) a.visible = e.target.checked; requestDraw(); };
  $('marks').onchange = (e) => { setMarks(e.target.checked); requestDraw(); };
  $('follow').onchange = () => { state.followPrev = currentFollowPoint(); };
  $('reset').onclick = () => { resetCamera(); requestDraw(); };
  $('channels').onchange = () => drawPlot();
  window.addEventListener('resize', resize);
  window.addEventListener('keydown', (e) => {
    if (e.target.tagName === 'SELECT') return;
    if (e.key === ' ') { setPlaying(!state.playing); e.preventDefault(); }
    const [k] = frameAt(state.time), t = state.c.time;
    if (e.key === 'ArrowRight') setTime(t[Math.min(k + 1, t.length - 1)]);
    if (e.key === 'ArrowLeft') setTime(t[Math.max(k - (state.time > t[k] ? 0 : 1), 0)]);
  });

  DATA.cases.forEach((c, i) => {
    const o = document.createElement('option'); o.value = i; o.textContent = c.label; $('case').appendChild(o);
  });
  $('case-box').style.display = DATA.cases.length > 1 ? '' : 'none';
  if (params.frames === '1') $('frames').checked = true;
  const first = Math.min(Math.max(parseInt(params['case'] || '0', 10) || 0, 0), DATA.cases.length - 1);
  $('case').value = first;
  setCase(first, params.channels ? params.channels.split(',') : null);
  if (params.follow !== undefined) $('follow').checked = params.follow === '1';
  if (params.t !== undefined) setTime(parseFloat(params.t));
  render(); // the first frame now, before the page's load event
  stats.firstFrameMs = performance.now();
  document.body.dataset.firstFrameMs = stats.firstFrameMs.toFixed(0);
  if (params.play === '1') setPlaying(true);
  window.addEventListener('hashchange', () => {
    const p = hashParams();
    if (p['case'] !== undefined && +p['case'] !== +$('case').value) { $('case').value = +p['case']; setCase(+p['case']); }
    if (p.t !== undefined) { setPlaying(false); setTime(parseFloat(p.t)); }
  });
  window.mbsimView = { setTime, setCase, setPlaying, stats, state, renderer, camera, scene };
})();
