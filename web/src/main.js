// The browser player page, built on the three.js module prt-character.js (PRTCharacter: posing, onnxruntime-web,
// the RPO shading of the learned visibility and the peaks): this file is an app of the module like any other - its
// own renderer, scene, camera (the Python player's: camera_eye around the character, or the site's per-frame follow
// track camera.follow[clip] = (cx, cy, cz, radius) per frame when `prt web` wrote one), a Lambert floor under the
// character that receives the sun's learned shadow (PRTFloor), the controls and keys, and window.prt, the page's scripting interface (used by `prt web --check`,
// `prt bench web` and tests/web).
// ?characters=K (1..64): K instances of the character in one draw on a grid, each with its own pose (clip c % #clips,
// 3 c frames later), the latent graph run once with batch K; ?texwidth=W forces the texture width (shading.js);
// ?decode=cpu: the whole visibility graph per frame; ?form=matrix: the matrix form of the shading; ?paused.
import * as THREE from 'three';
import * as ort from 'onnxruntime-web';
import { PRTCharacter, PRTFloor, PRTLighting } from './prt-character.js';
import { Poser } from './posing.js';
import { TEXTURE_WIDTH } from './shading.js';

const $ = (id) => document.getElementById(id);
const ASSETS = 'assets/';

function need(cond, message) {
  if (!cond) throw new Error(message);
}

function showError(message) {
  const el = $('error');
  el.hidden = false;
  el.textContent = `The player could not start:\n\n${message}`;
  $('stats').textContent = 'error';
  window.prt.error = String(message);
}

// prt_torch.player.player.camera_eye: orbit the centre at distance * radius, in front (-y) at azimuth 0 (scale: a
// crowd's grid, the camera pulled back)
function cameraEye(cam, azimuth, elevation, scale = 1) {
  const d = [Math.sin(azimuth) * Math.cos(elevation), -Math.cos(azimuth) * Math.cos(elevation), Math.sin(elevation)];
  const r = cam.distance * cam.radius * scale;
  return [cam.center[0] + r * d[0], cam.center[1] + r * d[1], cam.center[2] + r * d[2]];
}

// the page: one PRTCharacter (possibly K instances) in a scene of its own with a floor; the properties the tests
// and the UI use (brdf, lightAngle, light, peaksOn, unshadowed, perPixel, exposure, clip, frame) are the character's
// and its lighting's
class App {
  constructor(character, renderer) {
    const m = character.m;
    this.character = character;
    this.m = m;
    this.renderer = renderer;
    this.material = character.material;
    this.playing = true;
    this.cameraMode = 'follow'; // 'follow': the site's per-clip track where it has one (as `prt play`); 'fixed': the rest pose's
    this.azimuth = m.camera.azimuth;
    this.elevation = m.camera.elevation;
    this.stats = { pose_ms: 0, visibility_ms: 0, peaks_ms: 0, render_ms: 0, step_ms: 0, fps: 0, steps: 0, characters: character.nChars };
    this.hasPeaks = character.hasPeaks;
    this.hasTexture = character.hasTexture;
    this.nChars = character.nChars;
    this.gridScale = character.gridScale;
    this.offsets = character.offsets;
    this.decode = character.decode;
    this.layout = character.layout;
    this.basisLayout = character.basisLayout;
    const bg = m.background;
    renderer.setClearColor(new THREE.Color(bg[0], bg[1], bg[2]), 1);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(m.camera.view_angle, m.camera.width / m.camera.height, 0.01 * m.camera.radius,
      20 * m.camera.radius * this.gridScale);
    this.camera.up.set(...m.camera.up);
    this.scene.add(character);
    this.floor = new PRTFloor(character, { albedo: [0.3, 0.3, 0.3] }); // a child of the character: the sun's shadow
    this.applyCamera();
  }

  get clip() { return this.character.clip; }
  set clip(v) { this.character.clip = v; }
  get frame() { return this.character.frame; }
  set frame(v) { this.character.frame = v; }
  get clipInfo() { return this.character.clipInfo; }
  get brdf() { return this.character.brdf; }
  set brdf(v) { this.character.brdf = v; }
  get light() { return this.character.light; }
  set light(v) { this.character.lighting.preset = v; }
  get lightAngle() { return this.character.lighting.angle; }
  set lightAngle(v) { this.character.lighting.angle = v; }
  get peaksOn() { return this.character.peaksOn; }
  set peaksOn(v) { this.character.lighting.peaks = Boolean(v); }
  get unshadowed() { return this.character.unshadowed; }
  set unshadowed(v) { this.character.unshadowed = v; }
  get perPixel() { return this.character.perPixel; }
  set perPixel(v) { this.character.perPixel = v; }
  get exposure() { return this.character.toneMap; }
  set exposure(v) { this.character.toneMap = v; }
  get lastLatent() { return this.character.lastLatent; }
  get peakDirs() { return this.character.peakDirs; }
  get poser() { return this.character.poser; }
  get a() { return this.character.a; }
  activePeaks() { return this.character.activePeaks(); }
  applyBrdf() { this.character.applyUniforms(); }
  applyLight() { this.character.applyUniforms(); }

  // the camera's target now: the follow track's frame of the clip when the site has one (the Python side's rule,
  // consumed as written), else the manifest's fixed centre and radius
  target() {
    const cam = this.m.camera, f = cam.follow && cam.follow[this.clipInfo.name];
    if (!f || this.cameraMode !== 'follow') return cam;
    const i = 4 * Math.min(this.frame, f.length / 4 - 1);
    return { ...cam, center: [f[i], f[i + 1], f[i + 2]], radius: f[i + 3] };
  }

  applyCamera() {
    const t = this.target();
    const eye = cameraEye(t, this.azimuth, this.elevation, this.gridScale);
    this.eye = eye;
    this.center = t.center;
    this.camera.position.set(...eye);
    this.camera.lookAt(...t.center);
    this.camera.updateMatrixWorld();
    this.character.viewFrom(this.camera);
  }

  // one step: the character's update (posing, onnxruntime-web, state upload), then the frame drawn
  async step() {
    const t0 = performance.now();
    this.applyCamera();
    const c = await this.character.update();
    if (this.floor.visible) await this.floor.update();
    const t2p = performance.now();
    this.renderer.render(this.scene, this.camera);
    if (this.syncGpu) { // wait for the draw itself, not just its submission: read one pixel back
      const gl = this.renderer.getContext();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, this.onePixel || (this.onePixel = new Uint8Array(4)));
    }
    const t3 = performance.now();
    const s = this.stats;
    s.pose_ms = c.pose_ms; s.visibility_ms = c.visibility_ms; s.peaks_ms = c.peaks_ms; s.render_ms = t3 - t2p;
    s.step_ms = t3 - t0;
    s.steps += 1;
    return { ...s };
  }

  radiance(fromVisibility = false, instance = 0) { return this.character.radiance(this.renderer, fromVisibility, instance); }
  fillLatent(z, n) { return this.character.fillLatent(z, n); }
  fillState(c, pos, fr, vis, peakVis, target) { // target: the page itself = the character's own state
    return this.character.fillState(c, pos, fr, vis, peakVis, !target || target === this ? this.character : target);
  }
  get visInput() { return this.character.visInput; }
  runVisibility(f, b) { return this.character.runVisibility(f, b); }
  runLatent(f, b) { return this.character.runLatent(f, b); }
  runPeaks(...args) { return this.character.runPeaks(...args); }
  get peakSession() { return this.character.peakSession; }

  readPixels() {
    const gl = this.renderer.getContext();
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    let bin = '';
    for (let i = 0; i < px.length; i += 0x8000) bin += String.fromCharCode.apply(null, px.subarray(i, i + 0x8000));
    return { width: w, height: h, rgba: btoa(bin) };
  }
}

// -- UI ---------------------------------------------------------------------------------------------------
function bindUi(app) {
  const m = app.m;
  $('title').textContent = `${m.name} (${m.n_vertices} vertices, SH order ${m.order})`;
  const fill = (sel, names) => { sel.innerHTML = ''; names.forEach((n, i) => sel.add(new Option(n, i))); };
  fill($('clip'), m.clips.map((c) => c.name));
  fill($('env'), m.lights.map((l) => l.name));
  fill($('brdf'), m.rpos.map((r) => r.name));
  $('brdf').value = app.brdf;
  $('texRow').hidden = !app.hasTexture;
  const st = m.start || {};
  $('clipNote').textContent = st.clip ? `opened on ${st.clip}: ${st.clip_why}` : '';
  $('peaksRow').hidden = !app.hasPeaks;
  const sync = () => {
    $('clip').value = app.clip;
    $('frame').max = app.clipInfo.frames - 1;
    $('frame').value = app.frame;
    $('frameLabel').textContent = `${app.frame} / ${app.clipInfo.frames - 1}`;
    $('play').textContent = app.playing ? 'pause' : 'play';
    const deg = Math.round(((app.lightAngle * 180 / Math.PI) % 360 + 540) % 360 - 180);
    $('light').value = deg;
    $('lightLabel').textContent = `${deg}\u00b0`;
    $('env').value = app.light;
    $('brdf').value = app.brdf;
    $('unshadowed').checked = app.unshadowed;
    $('peaks').checked = app.peaksOn;
    $('follow').checked = app.cameraMode === 'follow';
    $('floor').checked = app.floor.visible;
  };
  app.sync = sync;
  $('clip').onchange = (e) => { app.clip = Number(e.target.value); app.frame = 0; sync(); };
  $('frame').oninput = (e) => { app.frame = Number(e.target.value); app.playing = false; sync(); };
  $('play').onclick = () => { app.playing = !app.playing; sync(); };
  $('light').oninput = (e) => { app.lightAngle = Number(e.target.value) * Math.PI / 180; app.applyLight(); sync(); };
  $('env').onchange = (e) => { app.light = Number(e.target.value); app.applyLight(); sync(); };
  $('brdf').onchange = (e) => { app.brdf = Number(e.target.value); app.applyBrdf(); sync(); };
  $('unshadowed').onchange = (e) => { app.unshadowed = e.target.checked; sync(); };
  $('peaks').onchange = (e) => { app.peaksOn = e.target.checked; app.applyLight(); sync(); };
  $('perPixel').onchange = (e) => { app.perPixel = e.target.checked; };
  $('floor').onchange = (e) => { app.floor.visible = e.target.checked; };
  $('follow').onchange = (e) => { app.cameraMode = e.target.checked ? 'follow' : 'fixed'; app.applyCamera(); };
  $('followRow').hidden = !(m.camera.follow && Object.keys(m.camera.follow).length);
  // keyboard shortcuts of the Python player (Player._bind_keys) plus playback keys
  window.addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLInputElement && e.target.type !== 'checkbox' && e.target.type !== 'range') return;
    const k = e.key;
    if (k === 'l') { app.lightAngle += 15 * Math.PI / 180; app.applyLight(); }
    else if (k === 'b') { app.brdf = (app.brdf + 1) % m.rpos.length; app.applyBrdf(); }
    else if (k === 'e') { app.light = (app.light + 1) % m.lights.length; app.applyLight(); }
    else if (k === 'u') app.unshadowed = !app.unshadowed;
    else if (k === 'p' && app.hasPeaks) { app.peaksOn = !app.peaksOn; app.applyLight(); }
    else if (k === ' ') app.playing = !app.playing;
    else if (k === ',') { app.playing = false; app.frame = Math.max(0, app.frame - 1); }
    else if (k === '.') { app.playing = false; app.frame = Math.min(app.clipInfo.frames - 1, app.frame + 1); }
    else if (k === 'ArrowLeft') { app.azimuth -= 10 * Math.PI / 180; app.applyCamera(); }
    else if (k === 'ArrowRight') { app.azimuth += 10 * Math.PI / 180; app.applyCamera(); }
    else if (k === 'ArrowUp') { app.elevation = Math.min(1.2, app.elevation + 8 * Math.PI / 180); app.applyCamera(); }
    else if (k === 'ArrowDown') { app.elevation = Math.max(-1.2, app.elevation - 8 * Math.PI / 180); app.applyCamera(); }
    else if (k === 'c') { app.cameraMode = app.cameraMode === 'follow' ? 'fixed' : 'follow'; app.applyCamera(); }
    else if (k === 'r') { app.azimuth = m.camera.azimuth; app.elevation = m.camera.elevation; app.applyCamera(); }
    else return;
    e.preventDefault();
    sync();
  });
  sync();
}

function loop(app) {
  let last = performance.now(), acc = 0, frames = 0, fpsT0 = last, busy = false;
  const tick = async () => {
    requestAnimationFrame(tick);
    if (busy || app.paused) return;
    busy = true;
    try {
      const now = performance.now();
      if (app.playing) {
        acc += (now - last) / 1000 * app.clipInfo.fps;
        const adv = Math.floor(acc);
        if (adv > 0) { acc -= adv; app.frame = (app.frame + adv) % app.clipInfo.frames; app.sync(); }
      }
      last = now;
      const s = await app.step();
      frames += 1;
      if (now - fpsT0 > 500) { app.stats.fps = frames * 1000 / (now - fpsT0); frames = 0; fpsT0 = now; }
      $('stats').textContent = `${app.clipInfo.name} ${app.frame}  ${app.m.rpos[app.brdf].name}  ${app.m.lights[app.light].name}` +
        `${app.unshadowed ? '  UNSHADOWED' : ''}${app.activePeaks() ? `  ${app.activePeaks().directions.length} peak(s)` : ''}` +
        `\n${app.nChars > 1 ? `${app.nChars} characters  ` : ''}step ${s.step_ms.toFixed(1)} ms (pose ${s.pose_ms.toFixed(1)}, ` +
        `${app.decode ? 'latent (GPU decode)' : 'visibility'} ${s.visibility_ms.toFixed(1)}, ` +
        `peaks ${s.peaks_ms.toFixed(1)}, draw submit ${s.render_ms.toFixed(1)})  ${app.stats.fps.toFixed(1)} fps`;
    } catch (e) {
      app.paused = true;
      showError(e.message || String(e));
    } finally {
      busy = false;
    }
  };
  requestAnimationFrame(tick);
}

async function start() {
  // from disk the module graph does not load in Chromium (index.html says so); a browser that loads it still may
  // not fetch the data
  if (location.protocol === 'file:') throw new Error('this page was opened from disk (file://), where the browser does not let it load its data: serve it with `prt web RUN --out DIR --serve` and open the printed http://127.0.0.1 address');
  THREE.ColorManagement.enabled = false; // the character's shader writes display colours itself
  const canvas = $('canvas');
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
  renderer.setPixelRatio(1);
  renderer.debug.onShaderError = (gl, program, vs, fs) => {
    const log = gl.getShaderInfoLog(vs) + '\n' + gl.getShaderInfoLog(fs) + '\n' + gl.getProgramInfoLog(program);
    throw new Error(`the RPO shader failed to compile:\n${log}`);
  };
  ort.env.wasm.numThreads = self.crossOriginIsolated ? Math.min(4, navigator.hardwareConcurrency || 1) : 1;
  window.prt.wasmThreads = ort.env.wasm.numThreads; // threads need cross-origin isolation (prt web --serve sends it)
  const params = new URLSearchParams(location.search);
  const character = await PRTCharacter.load(ASSETS, { renderer, lighting: new PRTLighting(), wasmPaths: './vendor/ort/',
    decode: params.get('decode') === 'cpu' ? 'cpu' : 'gpu',
    instances: params.has('characters') ? Number(params.get('characters')) : 1,
    texWidth: params.has('texwidth') ? Number(params.get('texwidth')) : TEXTURE_WIDTH });
  renderer.setSize(character.m.camera.width, character.m.camera.height, false);
  const app = new App(character, renderer);
  window.prt.app = app;
  bindUi(app);
  if (params.has('paused')) { app.playing = false; app.paused = true; }
  await app.step(); // compiles the shader: errors surface here
  loop(app);
  return app;
}

// scripting interface: prt.ready resolves once the first frame is drawn
window.prt = {
  error: null,
  app: null,
  ready: null,
  async setState(s) {
    const app = this.app;
    if ('clip' in s) app.clip = typeof s.clip === 'number' ? s.clip : app.m.clips.findIndex((c) => c.name === s.clip);
    if (app.clip < 0) throw new Error(`unknown clip ${s.clip}`);
    if ('frame' in s) app.frame = s.frame;
    if ('playing' in s) app.playing = s.playing;
    if ('paused' in s) app.paused = s.paused;
    if ('lightAngle' in s) app.lightAngle = s.lightAngle;
    if ('light' in s) app.light = typeof s.light === 'number' ? s.light : app.m.lights.findIndex((l) => l.name === s.light);
    if ('brdf' in s) app.brdf = typeof s.brdf === 'number' ? s.brdf : app.m.rpos.findIndex((r) => r.name === s.brdf);
    if (app.light < 0 || app.brdf < 0) throw new Error('unknown lighting or BRDF');
    if ('unshadowed' in s) app.unshadowed = s.unshadowed;
    if ('peaks' in s) app.peaksOn = Boolean(s.peaks) && app.hasPeaks;
    if ('perPixel' in s) app.perPixel = s.perPixel;
    if ('tonemap' in s) app.exposure = s.tonemap;
    if ('syncGpu' in s) app.syncGpu = s.syncGpu;
    if ('floor' in s) app.floor.visible = Boolean(s.floor);
    if ('camera' in s) {
      if (s.camera !== 'follow' && s.camera !== 'fixed') throw new Error(`camera must be "follow" or "fixed", not ${JSON.stringify(s.camera)}`);
      app.cameraMode = s.camera;
    }
    app.applyBrdf(); app.applyLight(); app.applyCamera();
    if (app.sync) app.sync();
  },
  async render() { return this.app.step(); },
  stats() { return { ...this.app.stats }; },
  readPixels() { return this.app.readPixels(); },
  async visibility(features, batch) { return Array.from(await this.app.runVisibility(Float32Array.from(features), batch)); },
  // onnxruntime-web's peak visibility (B*V*P) of given inputs (flat arrays; skin row-major 4x4 per joint)
  async peakVisibility(a) {
    need(this.app.peakSession, 'the site has no peak visibility model');
    return Array.from(await this.app.runPeaks(a.positions, a.normals, a.skin, a.directions, a.angular_radii, a.batch || 1));
  },
  // per-vertex radiance (V*3, before the base colour) of character 0 as last rendered, or of given per-vertex inputs
  // {positions (V*3), frames (V*9), visibility (V*NC), peakVisibility (V*4)} under the current settings; with the GPU
  // decode, no visibility but {latent (Gz*Kz, z of one character), latentDims [1, Gz, Kz]} or {features (A)} (the
  // latent graph run here): the visibility decoded on the GPU
  async radiance(inputs) {
    const app = this.app;
    const fromVis = Boolean(inputs && inputs.visibility && app.decode);
    if (inputs) {
      if (app.decode && inputs.features) app.fillLatent(await app.runLatent(Float32Array.from(inputs.features), 1), 1);
      else if (app.decode && inputs.latent) app.fillLatent({ data: Float32Array.from(inputs.latent), dims: inputs.latentDims }, 1);
      app.fillState(0, inputs.positions, inputs.frames, inputs.visibility, inputs.peakVisibility, fromVis ? app.visInput : app);
    }
    return Array.from(app.radiance(fromVis));
  },
  // per-vertex radiance (V*3) of character c as last rendered (a crowd page)
  radianceOf(c) { return Array.from(this.app.radiance(false, c)); }, // (re-shaded from the state as it is)
  // the crowd: the camera's eye, each character's grid offset (K*3) and pose {clip, frame} now, and the last z the
  // latent graph returned {data (K*Gz*Kz), dims} (GPU decode; else null)
  crowd() {
    const app = this.app, clips = app.m.clips;
    const z = app.lastLatent;
    return { eye: app.eye, offsets: Array.from(app.offsets), latent: z ? { data: Array.from(z.data), dims: Array.from(z.dims) } : null,
      poses: Array.from({ length: app.nChars }, (_, c) => {
      const ci = clips[(app.clip + c) % clips.length];
      return { clip: ci.name, frame: (app.frame + 3 * c) % ci.frames };
    }) };
  },
  // the latent graph's z (B*Gz*Kz) in onnxruntime-web for pose features (B*A): {data, dims}
  async latent(features, batch) {
    need(this.app.decode, 'the page runs no latent graph (no GPU decode)');
    const z = await this.app.runLatent(Float32Array.from(features), batch);
    return { data: Array.from(z.data), dims: Array.from(z.dims) };
  },
  // what the page is: decode path, characters, texture layouts, the GL renderer string
  info() {
    const app = this.app, gl = app.renderer.getContext();
    const e = gl.getExtension('WEBGL_debug_renderer_info');
    return { decode: app.decode ? 'gpu' : 'visibility graph', characters: app.nChars, state: app.layout,
      basis: app.basisLayout || null, renderer: e ? gl.getParameter(e.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
      maxTextureSize: gl.getParameter(gl.MAX_TEXTURE_SIZE), wasmThreads: this.wasmThreads };
  },
  // the floor: its vertices in the character's frame (n*3), each peak's visible fraction there (n*4), the residual
  // lighting's irradiance at +z, its colours (n*3)
  floor() {
    const f = this.app.floor;
    return { points: Array.from(f.points), visibility: Array.from(f.visibility), irradiance: f.irradiance,
      colors: Array.from(f.geometry.attributes.color.array), albedo: f.albedo, skin: Array.from(this.app.character.skins) };
  },
  activePeaks() { const pk = this.app.activePeaks(); return pk ? { directions: Array.from(this.app.peakDirs), angular_radii: pk.angular_radii } : null; },
  skin() { return Array.from(this.app.poser.skin); },
  pose(clip, frame) {
    const app = this.app;
    const c = app.m.clips.findIndex((x) => x.name === clip);
    const local = Poser.localFromClip(app.a[app.m.clips[c].array], frame, app.m.n_joints);
    const p = app.poser.pose(local);
    return { positions: Array.from(p.positions), normals: Array.from(p.normals), frames: Array.from(p.frames),
      features: Array.from(app.poser.features(local)) };
  },
};
window.addEventListener('error', (e) => { if (!window.prt.error) showError(e.message); });
window.addEventListener('unhandledrejection', (e) => { if (!window.prt.error) showError(e.reason && e.reason.message || String(e.reason)); });
window.prt.ready = start().catch((e) => { showError(e.message || String(e)); return null; });
