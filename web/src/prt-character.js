// prt-character.js: the three.js module of prt_torch's learned PRT. PRTCharacter.load(url) loads a site written by
// `prt web RUN --out DIR` (url: its assets folder, DIR/assets/, or its manifest.json) and gives a THREE.Group whose
// mesh shades the character by RPO shading (prt_shading.glsl) with the learned visibility from onnxruntime-web and
// the peaks (the sun as its own light, with its learned soft shadow); it lives in the app's own scene, camera and
// render loop next to ordinary three.js objects:
//
//     import { PRTCharacter, PRTLighting } from 'prt-torch-web';      // 'three' and 'onnxruntime-web' from the
//     const lighting = new PRTLighting({ preset: 'sky' });            // app's import map
//     const hero = await PRTCharacter.load('site/assets/', { renderer, lighting });
//     scene.add(hero);
//     renderer.setAnimationLoop(async (ms) => { await hero.update(ms / 1000); renderer.render(scene, camera); });
//
// update(time) poses the clip at `time` seconds (or setPose(clip, frame) / setPose(localTransforms), then
// update()), runs onnxruntime-web (pose -> z, the GPU decode; or the whole visibility graph for an export without
// latent.onnx) and the peak graph, and uploads the per-vertex state; the draw itself happens in the app's
// renderer.render: the mesh's onBeforeRender shades every vertex once into a float target (shadePass) seen from the
// camera being rendered, and the mesh then draws from it. The character's own frame is the run's (z up, metres of
// the character); the object can be moved, turned and scaled: the eye and the lighting's directions are taken into
// its local frame. A PRTLighting (preset by name or index, rotation about the world's z, peaks on/off) can be
// shared by any number of characters; each reads the preset of that name from its own site (its SH order, its tone
// map). The output is display-referred (tone-mapped and gamma-encoded by the shader, as the Python player shows it).
// PRTFloor(character) is a floor under it that receives the sun's learned shadow (the same peak graph).
//
// Material options: brdf (a name of the site's catalogue; default the site's start BRDF: the character's own
// material when it has one), unshadowed, perPixel (the base-colour texture per pixel), instances (K characters in
// one draw on a grid, each its own pose: clip (clip + c) % #clips, 3 c frames later), decode ('gpu' | 'cpu'),
// texWidth (the texel layout's width, shading.js).
import * as THREE from 'three';
import * as ort from 'onnxruntime-web';
import { Poser } from './posing.js';
import { MAX_PEAKS, PEAK_TEXEL, RADIANCE_WIDTH, TEXTURE_WIDTH, VIS_TEXEL, itemTexture, makeMaterial, rpoTexture, stateLayout,
  texelLayout } from './shading.js';

export const SITE_FORMAT = 'prt_torch.web/1';
export const MAX_INSTANCES = 64;
const DTYPES = { float32: Float32Array, float64: Float64Array, uint32: Uint32Array, int32: Int32Array, uint8: Uint8Array,
  float16: Uint16Array }; // float16: the raw bits, uploaded as HALF_FLOAT

// an error of the site's files (named in its message) or of the options: the page shows it as it is
export class AssetError extends Error {}

function need(cond, message) {
  if (!cond) throw new AssetError(message);
}

// the bytes of a fetched asset against its manifest entry ({bytes, sha256}; either may be absent in older sites)
async function checkBytes(buf, entry, label, what) {
  if (Number.isInteger(entry.bytes)) {
    need(buf.byteLength === entry.bytes, `${what} (${label}) has ${buf.byteLength} bytes, the manifest says ${entry.bytes} (truncated or stale: re-run \`prt web\`)`);
  }
  if (typeof entry.sha256 === 'string' && self.crypto && crypto.subtle) { // secure contexts only (127.0.0.1 is one)
    const hex = Array.from(new Uint8Array(await crypto.subtle.digest('SHA-256', buf)), (b) => b.toString(16).padStart(2, '0')).join('');
    need(hex === entry.sha256, `${what} (${label}) does not match the manifest's sha256 (damaged or stale: re-run \`prt web\`)`);
  }
}

// the site's assets folder: url as given (messages) and resolved against the document (fetches)
class Site {
  constructor(url) {
    let u = String(url || 'assets/');
    if (u.endsWith('.json')) { this.manifestName = u.slice(u.lastIndexOf('/') + 1); u = u.slice(0, u.lastIndexOf('/') + 1); }
    else { this.manifestName = 'manifest.json'; if (!u.endsWith('/')) u += '/'; }
    this.label = u;
    this.base = new URL(u, document.baseURI).href;
  }

  async fetch(name, what) {
    let res;
    try {
      res = await fetch(this.base + name);
    } catch (e) {
      throw new AssetError(`${what} (${this.label}${name}) could not be fetched: ${e.message}`);
    }
    if (!res.ok) throw new AssetError(`${what} (${this.label}${name}) is missing: HTTP ${res.status} ${res.statusText}`);
    return res;
  }

  async manifest() {
    const res = await this.fetch(this.manifestName, 'the run manifest');
    const text = await res.text();
    let m;
    try {
      m = JSON.parse(text);
    } catch (e) {
      throw new AssetError(`the run manifest (${this.label}${this.manifestName}) is malformed JSON: ${e.message}`);
    }
    need(m && typeof m === 'object', 'the run manifest is not a JSON object');
    need(m.format === SITE_FORMAT, `the run manifest has format ${JSON.stringify(m.format)}, expected "${SITE_FORMAT}" (re-run \`prt web\`)`);
    for (const key of ['n_vertices', 'order', 'n_terms', 'n_features', 'parents', 'clips', 'rpos', 'lights', 'camera', 'data', 'model', 'unshadowed', 'gaunt']) {
      need(key in m, `the run manifest has no "${key}" (re-run \`prt web\`)`);
    }
    need(Number.isInteger(m.order) && m.order >= 1 && m.order <= 8, `unsupported SH order ${m.order} (1..8)`);
    need(m.clips.length > 0 && m.rpos.length > 0 && m.lights.length > 0, 'the run manifest lists no clip, BRDF or lighting');
    return m;
  }

  async arrays(m) {
    const res = await this.fetch(m.data.file, 'the character data');
    const buf = await res.arrayBuffer();
    need(Number.isInteger(m.data.bytes), 'the run manifest gives no size of the character data (re-run `prt web`)');
    await checkBytes(buf, m.data, this.label + m.data.file, 'the character data');
    const out = {};
    for (const [name, e] of Object.entries(m.data.arrays)) {
      const T = DTYPES[e.dtype];
      need(T, `array ${name}: unknown dtype ${e.dtype}`);
      const count = e.shape.reduce((a, b) => a * b, 1);
      need(count * T.BYTES_PER_ELEMENT === e.bytes && e.offset % 8 === 0 && e.offset + e.bytes <= buf.byteLength,
        `array ${name} does not fit ${this.label}${m.data.file} (offset ${e.offset}, ${e.bytes} bytes)`);
      out[name] = new T(buf, e.offset, count);
    }
    const V = m.n_vertices;
    for (const [name, len] of [['rest_vertices', 3 * V], ['rest_normals', 3 * V], ['cluster', V], ['base_color', 3 * V]]) {
      need(out[name] && out[name].length === len, `array ${name} is missing or has the wrong size`);
    }
    return out;
  }

  async texture(name) {
    const res = await this.fetch(name, 'the base-colour texture');
    const bitmap = await createImageBitmap(await res.blob(), { imageOrientation: 'none', premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
    const tex = new THREE.Texture(bitmap);
    tex.flipY = false; // glTF: v = 0 is the image's top row
    tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
    tex.colorSpace = THREE.SRGBColorSpace; // SRGB8_ALPHA8: decoded to linear before filtering, as the Python player does
    tex.needsUpdate = true;
    return tex;
  }

  // an onnxruntime-web session of the graph of a manifest entry {file, bytes, sha256}
  async session(entry, what) {
    const bytes = await (await this.fetch(entry.file, what)).arrayBuffer();
    await checkBytes(bytes, entry, this.label + entry.file, what);
    try {
      return await ort.InferenceSession.create(new Uint8Array(bytes), { executionProviders: ['wasm'] });
    } catch (e) {
      const runtime = await missingRuntime(); // ort's own message for a missing runtime file names no file
      throw new AssetError(runtime || `${what} (${this.label}${entry.file}) could not be loaded by onnxruntime-web: ${e.message || e}`);
    }
  }
}

// onnxruntime-web's own runtime files (fetched by it, not by this module): the first one that cannot be had, or null
const ORT_RUNTIME = ['ort-wasm-simd-threaded.mjs', 'ort-wasm-simd-threaded.wasm'];
async function missingRuntime() {
  const base = typeof ort.env.wasm.wasmPaths === 'string' ? ort.env.wasm.wasmPaths : null;
  if (!base) return null;
  for (const f of ORT_RUNTIME) {
    const label = new URL(f, base).href.replace(new URL('./', document.baseURI).href, '');
    let res;
    try {
      res = await fetch(new URL(f, base), { method: 'HEAD' });
    } catch (e) {
      return `onnxruntime-web's wasm runtime (${label}) could not be fetched: ${e.message}`;
    }
    if (!res.ok) return `onnxruntime-web's wasm runtime (${label}) is missing: HTTP ${res.status} ${res.statusText} (re-run \`prt web\`)`;
  }
  return null;
}

// round z as the CPU path does (prt_torch.player.frame_kernels.quantize_latent: onnxruntime's int8 MatMulNBits input
// rounding): per block of `block` entries, s = max |z| / 127 (float32), z -> rint_even(z / s) * s; block 0: z as is.
// z (nChars, Gz, Kz) flat -> out: row c * G + g (g: the site's clusters), tz texels (4 tz floats) per row
function roundHalfEven(x) {
  const r = Math.round(x);
  return (Math.abs(x % 1) === 0.5 && r % 2 !== 0) ? r - 1 : r;
}
function quantizeLatent(z, zDims, groups, out, tz, nChars) {
  const gz = zDims[1], kz = zDims[2], f = Math.fround, ng = groups.length;
  for (let c = 0; c < nChars; c++) {
    for (let g = 0; g < ng; g++) {
      const { row, k_used: ku, block } = groups[g];
      const src = (c * gz + row) * kz, dst = (c * ng + g) * tz * 4;
      if (!block) { for (let k = 0; k < ku; k++) out[dst + k] = z[src + k]; continue; }
      for (let b0 = 0; b0 < ku; b0 += block) {
        const b1 = Math.min(ku, b0 + block);
        let amax = 0;
        for (let k = b0; k < b1; k++) amax = Math.max(amax, Math.abs(z[src + k]));
        const sc = f(amax / 127);
        for (let k = b0; k < b1; k++) out[dst + k] = sc > 0 ? f(roundHalfEven(f(z[src + k] / sc)) * sc) : 0;
      }
    }
  }
  return out;
}

// the context's MAX_TEXTURE_SIZE: of the app's renderer, else of a throwaway WebGL2 context
function maxTextureSize(renderer) {
  if (renderer) { const gl = renderer.getContext(); return gl.getParameter(gl.MAX_TEXTURE_SIZE); }
  const gl = document.createElement('canvas').getContext('webgl2');
  need(gl, 'WebGL2 is not available in this browser');
  const n = gl.getParameter(gl.MAX_TEXTURE_SIZE);
  const lose = gl.getExtension('WEBGL_lose_context');
  if (lose) lose.loseContext();
  return n;
}

// The lighting the app controls, shared by any number of characters: preset (a name or an index of the sites'
// lighting presets), angle (radians about the world's z, as the Python player's rotate_light), peaks (the presets'
// peak lights shaded on their own, with their learned shadow, where a site has them)
export class PRTLighting {
  constructor({ preset = 0, angle = 0, peaks = true } = {}) {
    this.preset = preset;
    this.angle = angle;
    this.peaks = peaks;
  }

  // the index of this lighting's preset among a site's lights (one-line error when it has none of that name)
  indexIn(lights) {
    const i = typeof this.preset === 'number' ? this.preset : lights.findIndex((l) => l.name === this.preset);
    need(Number.isInteger(i) && i >= 0 && i < lights.length,
      `unknown lighting ${JSON.stringify(this.preset)}: the site has ${lights.map((l) => l.name).join(', ')}`);
    return i;
  }
}

const identity3 = [1, 0, 0, 0, 1, 0, 0, 0, 1];

export class PRTCharacter extends THREE.Group {
  // url: the site's assets folder (or its manifest.json); options: renderer (its MAX_TEXTURE_SIZE), lighting (a
  // PRTLighting, default a new one), brdf, clip, instances, decode ('gpu' | 'cpu'), texWidth, wasmPaths (onnxruntime-
  // web's runtime folder; default onnxruntime-web's own: next to its module)
  static async load(url, options = {}) {
    const site = new Site(url);
    if (options.wasmPaths) ort.env.wasm.wasmPaths = new URL(options.wasmPaths, document.baseURI).href;
    const m = await site.manifest();
    const arrays = await site.arrays(m);
    const glsl = await shadingSource();
    // GPU decode: the latent graph per frame (the visibility graph only on demand); decode 'cpu': the whole
    // visibility graph per frame as for an export without a latent graph
    const gpuDecode = Boolean(m.decode) && options.decode !== 'cpu';
    const latentSession = gpuDecode ? await site.session(m.decode, 'the latent model') : null;
    const session = gpuDecode ? null : await site.session(m.model, 'the visibility model');
    const peakSession = m.peaks_model ? await site.session(m.peaks_model, 'the peak visibility model') : null;
    const texture = m.material && m.material.texture ? await site.texture(m.material.texture) : null;
    return new PRTCharacter({ site, m, arrays, glsl, session, latentSession, peakSession, texture }, options);
  }

  constructor({ site, m, arrays, glsl, session, latentSession, peakSession, texture }, options = {}) {
    super();
    this.name = m.name;
    this.site = site;
    this.m = m;
    this.a = arrays;
    this.session = session; // the visibility graph (GPU decode: loaded on demand, runVisibility)
    this.latentSession = latentSession; // the latent graph (null: no GPU decode, the visibility graph per frame)
    this.decode = latentSession ? m.decode : null;
    this.peakSession = peakSession; // the site's peak graph (null: peaks unshadowed)
    const V = m.n_vertices, nc = m.order * m.order;
    this.V = V;
    this.nc = nc;
    const nChars = options.instances === undefined ? 1 : options.instances;
    need(Number.isInteger(nChars) && nChars >= 1 && nChars <= MAX_INSTANCES, `characters must be 1..${MAX_INSTANCES}, not ${nChars}`);
    this.nChars = nChars;
    this.texWidth = options.texWidth || TEXTURE_WIDTH;
    this.maxTextureSize = maxTextureSize(options.renderer);
    const K = arrays.skin_weights.length / V;
    this.poser = new Poser(m.parents, arrays, K);
    need(this.poser.nFeatures === m.n_features, `the skeleton gives ${this.poser.nFeatures} pose features, the model takes ${m.n_features}`);
    if (this.decode) {
      const d = this.decode;
      need(arrays[d.basis] && arrays[d.basis].length === V * 4 * d.texels && arrays[d.rows] && arrays[d.rows].length === 2 * V,
        'the GPU decode\'s arrays are missing or have the wrong size (re-run `prt web`)');
    }
    this.posed = Array.from({ length: nChars }, () => null);
    this.visibility = new Float32Array(nChars * V * nc);
    this.peakVis = new Float32Array(nChars * V * MAX_PEAKS).fill(1); // (K, V, 4): peak p's visible fraction at vertex v
    this.skins = new Float32Array(nChars * m.n_joints * 16); // (K, J, 4, 4) each character's skinning matrices
    this.offsets = this.gridOffsets(nChars);
    this.hasPeaks = m.lights.some((l) => l.peaks);
    this.lighting = options.lighting || new PRTLighting();
    this.peakDirs = new Float32Array(0); // (P, 3) the active peaks' directions in the character's frame
    const start = m.start || {};
    this.clip = 0;
    if (options.clip !== undefined) this.clip = this.clipIndex(options.clip);
    else if (start.clip) this.clip = Math.max(0, m.clips.findIndex((c) => c.name === start.clip));
    this.frame = 0;
    this.local = null; // setPose(localTransforms): the pose given, else the clip's frame
    const brdf = options.brdf !== undefined ? options.brdf : (start.brdf || m.default_brdf);
    this.brdf = typeof brdf === 'number' ? brdf : Math.max(0, m.rpos.findIndex((r) => r.name === brdf));
    this.unshadowed = false;
    this.toneMap = null; // {exposure, white} override; null: fixed per lighting preset by `prt web` (the player's rule)
    // pose_ms: posing (JS: features + LBS + frames), visibility_ms: the wasm inference (latent or visibility graph),
    // peaks_ms: the peak graph
    this.stats = { pose_ms: 0, visibility_ms: 0, peaks_ms: 0, steps: 0, characters: nChars };
    this.hasTexture = Boolean(texture) && Boolean(arrays.uv);
    this.perPixel = this.hasTexture;
    this.eyeLocal = new THREE.Vector3(0, -1, 0);
    this.passCamera = new THREE.Camera(); // the shading pass draws points at fixed pixels: no camera of its own
    this.initThree(glsl, texture);
  }

  // the lowest point of the rest mesh (the character's floor height, z) and its centre / radius (manifest camera)
  get floorHeight() {
    const rest = this.a.rest_vertices;
    let lo = Infinity;
    for (let v = 0; v < this.V; v++) lo = Math.min(lo, rest[3 * v + 2]);
    return lo;
  }

  clipIndex(clip) {
    const i = typeof clip === 'number' ? clip : this.m.clips.findIndex((c) => c.name === clip);
    need(Number.isInteger(i) && i >= 0 && i < this.m.clips.length, `unknown clip ${clip}: the site has ${this.m.clips.map((c) => c.name).join(', ')}`);
    return i;
  }

  get clipInfo() { return this.m.clips[this.clip]; }

  // the pose of the next update: a clip (name or index) and frame, or local joint transforms (J*16 row-major 4x4)
  setPose(clip, frame = 0) {
    if (ArrayBuffer.isView(clip) || Array.isArray(clip)) {
      need(clip.length === 16 * this.m.n_joints, `setPose: ${clip.length} numbers, expected ${16 * this.m.n_joints} (J 4x4 local transforms)`);
      this.local = Float64Array.from(clip);
      return;
    }
    this.local = null;
    this.clip = this.clipIndex(clip);
    need(Number.isInteger(frame), `setPose: frame must be an integer, not ${frame}`);
    const n = this.clipInfo.frames;
    this.frame = ((frame % n) + n) % n;
  }

  // (K*3) offsets of K instances on a square grid, 1.5 x the rest mesh's horizontal extent apart, centred
  gridOffsets(n) {
    const rest = this.a.rest_vertices;
    const lo = [Infinity, Infinity], hi = [-Infinity, -Infinity];
    for (let v = 0; v < this.V; v++) for (let e = 0; e < 2; e++) { lo[e] = Math.min(lo[e], rest[3 * v + e]); hi[e] = Math.max(hi[e], rest[3 * v + e]); }
    const step = 1.5 * Math.max(hi[0] - lo[0], hi[1] - lo[1]);
    const cols = Math.ceil(Math.sqrt(n)), rows = Math.ceil(n / cols);
    this.gridScale = n > 1 ? 1 + step * (cols - 1) / this.m.camera.radius : 1;
    const out = new Float32Array(3 * n);
    for (let c = 0; c < n; c++) {
      out[3 * c] = (c % cols - (cols - 1) / 2) * step;
      out[3 * c + 1] = (Math.floor(c / cols) - (rows - 1) / 2) * step;
    }
    return out;
  }

  initThree(glsl, texture) {
    const m = this.m;
    const maxSize = this.maxTextureSize;
    this.layout = stateLayout(this.nChars * this.V, this.nc, Boolean(this.decode), this.texWidth, maxSize);
    this.state = new Float32Array(this.layout.width * this.layout.height * 4);
    this.stateTex = itemTexture(this.state, this.layout);
    this.decodeOptions = null;
    if (this.decode) {
      const d = this.decode, ng = d.groups.length;
      this.basisLayout = texelLayout(this.V, d.texels, this.texWidth, maxSize, 'the GPU decode\'s basis texture');
      this.basisTex = itemTexture(this.a[d.basis], this.basisLayout);
      this.tz = Math.max(1, Math.ceil(d.k_max / 4));
      this.latent = new Float32Array(this.tz * 4 * ng * this.nChars);
      this.latentTex = itemTexture(this.latent, { width: this.tz, height: ng * this.nChars });
      this.decodeOptions = { layout: this.basisLayout, latentRows: ng };
    }
    const sizes = { order: m.order, nTerms: m.n_terms, nLobes: m.lights[0].dirs.length };
    for (const l of m.lights) {
      need(l.dirs.length === sizes.nLobes && (!l.peaks || l.peaks.dirs.length === sizes.nLobes),
        `lighting ${l.name}: every lighting (and its residual) must have ${sizes.nLobes} lobes`);
      need(!l.peaks || l.peaks.directions.length <= MAX_PEAKS, `lighting ${l.name}: at most ${MAX_PEAKS} peaks`);
    }
    this.sizes = sizes;
    this.glsl = glsl;
    this.matrixForm = new URLSearchParams(location.search).get('form') === 'matrix';
    this.material = makeMaterial(glsl, sizes, this.layout, m.gaunt, this.matrixForm, { decode: this.decodeOptions,
      fromRadiance: true });
    const u = this.material.uniforms;
    u.u_state.value = this.stateTex;
    u.u_nVertices.value = this.V;
    if (this.decode) { u.u_basis.value = this.basisTex; u.u_latent.value = this.latentTex; }
    u.u_unshadowedVis.value.set(m.unshadowed);
    u.u_gamma.value = m.tonemap.gamma;
    const mat = m.material || {};
    u.u_baseFactor.value.set(...(mat.base_color || [1, 1, 1]).slice(0, 3));
    u.u_baseTex.value = texture || null;
    this.rpoTex = m.rpos.map((r) => rpoTexture(this.a[r.M], m.n_terms, this.nc));
    // geometry: indexed (one shading per vertex); non-indexed per corner when a texture needs corner UVs
    const g = new THREE.InstancedBufferGeometry(); // one instance per character (a_instance)
    g.instanceCount = this.nChars;
    g.setAttribute('a_instance', new THREE.InstancedBufferAttribute(Float32Array.from({ length: this.nChars }, (_, i) => i), 1));
    const faces = this.a.faces, base = this.a.base_color, rest = this.a.rest_vertices;
    const rows = this.decode ? this.a[this.decode.rows] : null;
    if (this.hasTexture) {
      const n = faces.length;
      const vid = new Float32Array(n), uv = new Float32Array(2 * n), b3 = new Float32Array(3 * n), p3 = new Float32Array(3 * n);
      const dec = new Float32Array(2 * n);
      for (let c = 0; c < n; c++) {
        const v = faces[c];
        vid[c] = v;
        uv[2 * c] = this.a.uv[2 * c]; uv[2 * c + 1] = this.a.uv[2 * c + 1];
        for (let e = 0; e < 3; e++) { b3[3 * c + e] = base[3 * v + e]; p3[3 * c + e] = rest[3 * v + e]; }
        if (rows) { dec[2 * c] = rows[2 * v]; dec[2 * c + 1] = rows[2 * v + 1]; }
      }
      g.setAttribute('position', new THREE.BufferAttribute(p3, 3));
      g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
      g.setAttribute('a_uv', new THREE.BufferAttribute(uv, 2));
      g.setAttribute('a_base', new THREE.BufferAttribute(b3, 3));
      if (rows) g.setAttribute('a_decode', new THREE.BufferAttribute(dec, 2));
    } else {
      const vid = new Float32Array(this.V);
      for (let v = 0; v < this.V; v++) vid[v] = v;
      g.setAttribute('position', new THREE.BufferAttribute(rest, 3));
      g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
      g.setAttribute('a_uv', new THREE.BufferAttribute(new Float32Array(2 * this.V), 2));
      g.setAttribute('a_base', new THREE.BufferAttribute(base, 3));
      if (rows) g.setAttribute('a_decode', new THREE.BufferAttribute(rows, 2));
      g.setIndex(new THREE.BufferAttribute(faces, 1));
    }
    this.initShadingPass();
    this.mesh = new THREE.Mesh(g, this.material);
    this.mesh.name = `${m.name} (PRT)`;
    this.mesh.frustumCulled = false; // positions come from the state texture
    // the shading pass of the camera being rendered, inside the app's own renderer.render (as three's Reflector
    // renders its target)
    this.mesh.onBeforeRender = (renderer, scene, camera) => {
      this.viewFrom(camera);
      this.shadePass(renderer);
    };
    this.add(this.mesh);
    this.applyUniforms();
  }

  // the frame's first pass: every instance's vertices decoded + shaded once, one point each, into a float target
  // (RADIANCE_WIDTH x ceil(K V / RADIANCE_WIDTH)) the mesh pass reads
  initShadingPass() {
    const n = this.nChars * this.V;
    this.shadeRows = Math.ceil(n / RADIANCE_WIDTH);
    const mat = makeMaterial(this.glsl, this.sizes, this.layout, this.m.gaunt, this.matrixForm,
      { radianceOut: true, uniforms: this.material.uniforms, decode: this.decodeOptions });
    const g = new THREE.InstancedBufferGeometry();
    g.instanceCount = this.nChars;
    g.setAttribute('a_instance', new THREE.InstancedBufferAttribute(Float32Array.from({ length: this.nChars }, (_, i) => i), 1));
    const vid = new Float32Array(this.V);
    for (let v = 0; v < this.V; v++) vid[v] = v;
    g.setAttribute('position', new THREE.BufferAttribute(this.a.rest_vertices, 3));
    g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
    g.setAttribute('a_uv', new THREE.BufferAttribute(new Float32Array(2 * this.V), 2));
    g.setAttribute('a_base', new THREE.BufferAttribute(this.a.base_color, 3));
    if (this.decode) g.setAttribute('a_decode', new THREE.BufferAttribute(this.a[this.decode.rows], 2));
    const pts = new THREE.Points(g, mat);
    pts.frustumCulled = false;
    this.shadeScene = new THREE.Scene();
    this.shadeScene.add(pts);
    this.shadeTarget = new THREE.WebGLRenderTarget(RADIANCE_WIDTH, this.shadeRows, { type: THREE.FloatType,
      format: THREE.RGBAFormat, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: false });
    this.material.uniforms.u_radianceTex.value = this.shadeTarget.texture;
  }

  // a pass into `target` of `scene` (the renderer's target, clear colour and autoClear as they were afterwards)
  passInto(renderer, target, scene) {
    const r = renderer;
    const prev = r.getRenderTarget();
    const clear = new THREE.Color();
    r.getClearColor(clear);
    const alpha = r.getClearAlpha();
    r.setRenderTarget(target);
    r.setClearColor(new THREE.Color(0, 0, 0), 0);
    r.clear();
    r.render(scene, this.passCamera);
    r.setRenderTarget(prev);
    r.setClearColor(clear, alpha);
  }

  // the shading pass (decode + shade every vertex once) into its target, under the uniforms as they are now
  shadePass(renderer) {
    this.applyUniforms();
    this.material.uniforms.u_radianceRows.value = this.shadeRows;
    this.passInto(renderer, this.shadeTarget, this.shadeScene);
  }

  // the rotation part of the inverse of the object's world matrix (row-major 3x3): world directions -> its frame
  worldToLocal3() {
    this.updateWorldMatrix(true, false);
    const e = this.matrixWorld.elements; // column-major
    const cols = [[e[0], e[1], e[2]], [e[4], e[5], e[6]], [e[8], e[9], e[10]]].map((c) => {
      const n = Math.hypot(c[0], c[1], c[2]);
      return [c[0] / n, c[1] / n, c[2] / n];
    });
    if (cols.every((c, j) => c.every((x, i) => x === identity3[3 * i + j]))) return identity3;
    return [cols[0][0], cols[0][1], cols[0][2], cols[1][0], cols[1][1], cols[1][2], cols[2][0], cols[2][1], cols[2][2]];
  }

  // the eye of `camera` (its world position) in the character's frame
  viewFrom(camera) {
    camera.updateWorldMatrix(true, false);
    this.updateWorldMatrix(true, false);
    const eye = new THREE.Vector3().setFromMatrixPosition(camera.matrixWorld);
    const inv = this.matrixWorld.clone().invert();
    this.eyeLocal.copy(this.matrixWorld.equals(new THREE.Matrix4()) ? eye : eye.applyMatrix4(inv));
    this.material.uniforms.u_eye.value.copy(this.eyeLocal);
  }

  // the lighting's preset entry of this site
  get light() { return this.lighting.indexIn(this.m.lights); }
  get peaksOn() { return Boolean(this.lighting.peaks) && this.hasPeaks; }

  // the lighting's peaks when they are shaded (peaks on, the preset has some, the BRDF is analytic), else null
  activePeaks() {
    const pk = this.m.lights[this.light].peaks;
    return this.lighting.peaks && pk && this.m.rpos[this.brdf].brdf ? pk : null;
  }

  // BRDF, lighting (rotated about the world's z by its angle, then into the character's frame), tone map
  applyUniforms() {
    const m = this.m, u = this.material.uniforms;
    need(Number.isInteger(this.brdf) && this.brdf >= 0 && this.brdf < m.rpos.length, `unknown BRDF ${this.brdf}`);
    const r = m.rpos[this.brdf];
    u.u_rpoM.value = this.rpoTex[this.brdf];
    u.u_rpoW.value.set(this.a[r.w]);
    u.u_rpoU.value.set(this.a[r.u]);
    u.u_tint.value.set(...r.tint);
    if (r.brdf) { // null: an RPO of no known BRDF, no peak term
      u.u_brdfKind.value = r.brdf.kind;
      u.u_brdfParams.value.set(...r.brdf.params);
    }
    const lt = m.lights[this.light];
    const c = Math.cos(this.lighting.angle), s = Math.sin(this.lighting.angle);
    const R = this.worldToLocal3();
    const turn = (d) => { // dirs @ R^T, R = rotation about z by the angle (Player.rotate_light); then world -> local
      const w = [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]];
      if (R === identity3) return w;
      return [R[0] * w[0] + R[1] * w[1] + R[2] * w[2], R[3] * w[0] + R[4] * w[1] + R[5] * w[2], R[6] * w[0] + R[7] * w[1] + R[8] * w[2]];
    };
    const pk = this.activePeaks();
    const lobes = pk || lt; // peaks on: the residual's lobes on the SH path
    lobes.dirs.forEach((d, k) => u.u_lobeDir.value[k].set(...turn(d)));
    lobes.coeffs.forEach((bands, k) => bands.forEach((rgb, l) => u.u_lobeG.value[k * m.order + l].set(...rgb)));
    const n = pk ? pk.directions.length : 0;
    u.u_nPeaks.value = n;
    this.peakDirs = new Float32Array(3 * n);
    for (let p = 0; p < n; p++) {
      this.peakDirs.set(turn(pk.directions[p]), 3 * p);
      u.u_peakDir.value[p].set(...this.peakDirs.subarray(3 * p, 3 * p + 3));
      u.u_peakPower.value[p].set(...pk.powers[p]);
    }
    const tm = this.toneMap || (pk && pk.tonemap) || lt.tonemap;
    u.u_exposure.value = tm.exposure;
    u.u_white.value = tm.white;
    u.u_unshadowed.value = this.unshadowed;
    u.u_perPixel.value = this.perPixel && this.hasTexture;
  }

  // instance c's local transforms now: the pose given (setPose(array)), else clip (clip + c) % #clips, frame
  // (frame + 3 c) % its frames
  localNow(c = 0) {
    if (this.local && c === 0) return this.local;
    const clips = this.m.clips, ci = clips[(this.clip + c) % clips.length];
    return Poser.localFromClip(this.a[ci.array], (this.frame + 3 * c) % ci.frames, this.m.n_joints);
  }

  async runVisibility(features, batch = 1) {
    if (!this.session) this.session = await this.site.session(this.m.model, 'the visibility model');
    const input = new ort.Tensor('float32', features, [batch, this.m.n_features]);
    const out = await this.session.run({ [this.m.model.input]: input });
    return out[this.m.model.output].data;
  }

  // z (batch, Gz, Kz) of the latent graph for pose features (batch * A): {data, dims}
  async runLatent(features, batch = 1) {
    const d = this.decode;
    const input = new ort.Tensor('float32', features, [batch, this.m.n_features]);
    const out = (await this.latentSession.run({ [d.input]: input }))[d.output];
    return { data: out.data, dims: out.dims };
  }

  // the latent texture from z of nChars instances (rounded as the CPU path does, quantizeLatent)
  fillLatent(z, nChars = this.nChars) {
    need(z.dims.length === 3 && z.dims[0] >= nChars && this.decode.groups.every((g) => g.row < z.dims[1] && g.k_used <= z.dims[2]),
      `the latent graph returned z of shape [${z.dims}], the site's decode needs ${nChars} x clusters x k`);
    quantizeLatent(z.data, z.dims, this.decode.groups, this.latent, this.tz, nChars);
    this.lastLatent = z; // z as the graph returned it
    this.latentTex.needsUpdate = true;
  }

  // peak visibility (B, V, P) of posed positions / normals (B*V*3) and skinning matrices (B*J*16, row-major 4x4)
  async runPeaks(positions, normals, skin, directions, radii, batch = 1) {
    const V = positions.length / (3 * batch), P = radii.length, J = this.m.n_joints;
    const f32 = (a) => (a instanceof Float32Array ? a : Float32Array.from(a));
    const feeds = {
      positions: new ort.Tensor('float32', f32(positions), [batch, V, 3]),
      normals: new ort.Tensor('float32', f32(normals), [batch, V, 3]),
      skin: new ort.Tensor('float32', f32(skin), [batch, J, 4, 4]),
      directions: new ort.Tensor('float32', f32(directions), [P, 3]),
      angular_radii: new ort.Tensor('float32', f32(radii), [P]),
    };
    const out = await this.peakSession.run(feeds);
    return out[this.m.peaks_model.output].data;
  }

  // instance c's items of the state texture from per-vertex arrays: positions (V*3, moved by the instance's grid
  // offset), frames (V*9), visibility (V*NC; GPU decode: unused), peak visibility (V*4, peak p of vertex v at 4v + p);
  // visibility null leaves the coefficients as they are
  // (target: {layout, state, stateTex}, default the character's own state; visInput's holds the coefficients)
  fillState(c, pos, fr, vis, peakVis, target = this) {
    const { P, R } = target.layout;
    const st = target.state, nc = this.nc, V = this.V;
    const ox = this.offsets[3 * c], oy = this.offsets[3 * c + 1], oz = this.offsets[3 * c + 2];
    const withVis = vis && P > VIS_TEXEL;
    for (let v = 0; v < V; v++) {
      const i = c * V + v;
      const o = 4 * ((Math.floor(i / R) * R * P) + (i % R) * P);
      st[o] = pos[3 * v] + ox; st[o + 1] = pos[3 * v + 1] + oy; st[o + 2] = pos[3 * v + 2] + oz;
      for (let r = 0; r < 3; r++) {
        st[o + 4 * (r + 1)] = fr[9 * v + 3 * r];
        st[o + 4 * (r + 1) + 1] = fr[9 * v + 3 * r + 1];
        st[o + 4 * (r + 1) + 2] = fr[9 * v + 3 * r + 2];
      }
      const q = o + 4 * PEAK_TEXEL;
      for (let p = 0; p < MAX_PEAKS; p++) st[q + p] = peakVis[MAX_PEAKS * v + p];
      if (withVis) for (let k = 0; k < nc; k++) st[o + 4 * VIS_TEXEL + k] = vis[v * nc + k];
    }
    target.stateTex.needsUpdate = true;
  }

  // with the GPU decode: a state texture of instance 0 with the visibility coefficients in it (radiance of a given
  // visibility: the shading checked on its own), drawn by a material without PRT_GPU_DECODE
  get visInput() {
    if (!this._visInput) {
      const layout = stateLayout(this.V, this.nc, false, this.texWidth, this.maxTextureSize);
      const state = new Float32Array(layout.width * layout.height * 4);
      this._visInput = { layout, state, stateTex: itemTexture(state, layout) };
    }
    return this._visInput;
  }

  // pose every instance (at `time` seconds of its clip when given: frame floor(time fps) mod frames), run the model
  // once for all of them (latent graph, or the visibility graph) and the peak graph, and fill the state the next
  // render draws; each part timed apart (this.stats)
  async update(time) {
    if (time !== undefined && time !== null) {
      need(Number.isFinite(time), `update: time must be a finite number of seconds, not ${time}`);
      this.local = null;
      const ci = this.clipInfo;
      this.frame = ((Math.floor(time * ci.fps) % ci.frames) + ci.frames) % ci.frames;
    }
    this.applyUniforms(); // the peaks' directions in the character's frame
    const t0 = performance.now();
    const K = this.nChars, V = this.V, A = this.m.n_features, nc = this.nc;
    const locals = [], feats = new Float32Array(K * A);
    for (let c = 0; c < K; c++) { locals.push(this.localNow(c)); feats.set(this.poser.features(locals[c]), c * A); }
    const tf = performance.now();
    if (!this.unshadowed) {
      if (this.decode) this.fillLatent(await this.runLatent(feats, K));
      else this.visibility = await this.runVisibility(feats, K);
    }
    const t1 = performance.now();
    const J16 = 16 * this.m.n_joints;
    for (let c = 0; c < K; c++) {
      this.posed[c] = this.poser.pose(locals[c], this.posed[c]);
      this.skins.set(this.poser.skin, c * J16);
    }
    const t2 = performance.now();
    const pk = this.activePeaks();
    if (pk && this.peakSession && !this.unshadowed) {
      const n = pk.directions.length;
      const cat = (key) => { const o = new Float32Array(K * 3 * V); this.posed.forEach((p, c) => o.set(p[key], c * 3 * V)); return o; };
      const pv = await this.runPeaks(cat('positions'), cat('normals'), this.skins, this.peakDirs, pk.angular_radii, K);
      for (let i = 0; i < K * V; i++) for (let p = 0; p < n; p++) this.peakVis[MAX_PEAKS * i + p] = pv[n * i + p];
    } else {
      this.peakVis.fill(1); // unshadowed, or no peak graph: the BRDF's horizon only
    }
    const t2p = performance.now();
    for (let c = 0; c < K; c++) {
      this.fillState(c, this.posed[c].positions, this.posed[c].frames,
        this.unshadowed ? null : this.visibility.subarray(c * V * nc, (c + 1) * V * nc),
        this.peakVis.subarray(c * V * MAX_PEAKS, (c + 1) * V * MAX_PEAKS));
    }
    const s = this.stats;
    s.pose_ms = (tf - t0) + (t2 - t1); s.visibility_ms = t1 - tf; s.peaks_ms = t2p - t2;
    s.steps += 1;
    return { ...s };
  }

  // per-vertex radiance (V*3, before the base colour) of the state as it is, through the same vertex shader, one
  // point per vertex into a float target, seen from the eye of the last viewFrom (fromVisibility: of the visInput
  // state, the coefficients given, not decoded, instance 0; else the shading pass, instance `instance`'s vertices)
  radiance(renderer, fromVisibility = false, instance = 0) {
    need(Number.isInteger(instance) && instance >= 0 && instance < (fromVisibility ? 1 : this.nChars), `no character ${instance}`);
    const r = renderer, V = this.V;
    const u = this.material.uniforms;
    if (!(fromVisibility && this.decode)) {
      this.shadePass(r);
      const px = new Float32Array(RADIANCE_WIDTH * this.shadeRows * 4);
      r.readRenderTargetPixels(this.shadeTarget, 0, 0, RADIANCE_WIDTH, this.shadeRows, px);
      const out = new Float32Array(3 * V);
      for (let v = 0; v < V; v++) for (let e = 0; e < 3; e++) out[3 * v + e] = px[4 * (instance * V + v) + e];
      return out;
    }
    if (!this.visScene) {
      const rows = Math.ceil(V / RADIANCE_WIDTH);
      const uniforms = { ...this.material.uniforms, u_state: { value: this.visInput.stateTex } };
      const mat = makeMaterial(this.glsl, this.sizes, this.visInput.layout, this.m.gaunt, this.matrixForm,
        { radianceOut: true, uniforms });
      const g = new THREE.BufferGeometry();
      const vid = new Float32Array(V);
      for (let v = 0; v < V; v++) vid[v] = v;
      g.setAttribute('position', new THREE.BufferAttribute(this.a.rest_vertices, 3));
      g.setAttribute('a_vid', new THREE.BufferAttribute(vid, 1));
      g.setAttribute('a_uv', new THREE.BufferAttribute(new Float32Array(2 * V), 2));
      g.setAttribute('a_base', new THREE.BufferAttribute(this.a.base_color, 3));
      g.setAttribute('a_instance', new THREE.BufferAttribute(new Float32Array(V), 1)); // instance 0
      const pts = new THREE.Points(g, mat);
      pts.frustumCulled = false;
      this.visScene = new THREE.Scene();
      this.visScene.add(pts);
      this.visTarget = new THREE.WebGLRenderTarget(RADIANCE_WIDTH, rows, { type: THREE.FloatType,
        format: THREE.RGBAFormat, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: false });
      this.visRows = rows;
    }
    this.applyUniforms();
    u.u_radianceRows.value = this.visRows;
    this.passInto(r, this.visTarget, this.visScene);
    const px = new Float32Array(RADIANCE_WIDTH * this.visRows * 4);
    r.readRenderTargetPixels(this.visTarget, 0, 0, RADIANCE_WIDTH, this.visRows, px);
    const out = new Float32Array(3 * V);
    for (let v = 0; v < V; v++) for (let e = 0; e < 3; e++) out[3 * v + e] = px[4 * v + e];
    return out;
  }

  // the GPU resources of this character (textures, targets, materials, geometries)
  dispose() {
    for (const t of [this.stateTex, this.basisTex, this.latentTex, ...this.rpoTex, this.material.uniforms.u_baseTex.value,
      this.shadeTarget, this.visTarget, this._visInput && this._visInput.stateTex]) if (t) t.dispose();
    for (const o of [this.mesh, ...this.shadeScene.children, ...(this.visScene ? this.visScene.children : [])]) {
      o.geometry.dispose();
      o.material.dispose();
    }
  }
}

// the shading GLSL, next to this module
let glslSource = null;
async function shadingSource() {
  if (!glslSource) {
    const url = new URL('./prt_shading.glsl', import.meta.url);
    let res;
    try {
      res = await fetch(url);
    } catch (e) {
      throw new AssetError(`the shading source (${url.href}) could not be fetched: ${e.message}`);
    }
    if (!res.ok) throw new AssetError(`the shading source (prt_shading.glsl next to prt-character.js) is missing: HTTP ${res.status} ${res.statusText}`);
    glslSource = await res.text();
  }
  return glslSource;
}

// Lambert's irradiance kernel per band (Ramamoorthi-Hanrahan): A_0 = pi, A_1 = 2 pi / 3, odd l > 1: 0, even l:
// 2 pi (-1)^(l/2 - 1) / ((l + 2)(l - 1)) l! / (2^l ((l/2)!)^2)
export function lambertBand(l) {
  if (l === 1) return 2 * Math.PI / 3;
  if (l % 2 === 1) return 0;
  let f = 1; // l! / (2^l ((l/2)!)^2)
  for (let i = 1; i <= l; i++) f *= i / 2;
  for (let i = 1; i <= l / 2; i++) f /= i * i;
  return 2 * Math.PI * (l / 2 % 2 === 1 ? 1 : -1) / ((l + 2) * (l - 1)) * f;
}

// irradiance (RGB) at unit normal n of ZH lobes (dirs (K, 3), coeffs (K, ORDER) RGB; the shader's convention: SH
// f_lm = g_kl y_lm(s_k)): E(n) = sum_k sum_l A_l g_kl (2l + 1) / (4 pi) P_l(s_k . n)
export function lobeIrradiance(dirs, coeffs, n) {
  const out = [0, 0, 0];
  dirs.forEach((d, k) => {
    const x = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
    let p0 = 1, p1 = x;
    coeffs[k].forEach((rgb, l) => {
      const pl = l === 0 ? 1 : l === 1 ? x : (() => { const p = ((2 * l - 1) * x * p1 - (l - 1) * p0) / l; p0 = p1; p1 = p; return p; })();
      const w = lambertBand(l) * (2 * l + 1) / (4 * Math.PI) * pl;
      for (let e = 0; e < 3; e++) out[e] += w * rgb[e];
    });
  });
  return out;
}

const FLOOR_VERTEX = `
in vec3 position;
in vec3 color;
uniform mat4 modelViewMatrix;
uniform mat4 projectionMatrix;
out vec3 v_color;
void main() { v_color = color; gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }`;
const FLOOR_FRAGMENT = `
in vec3 v_color;
out vec4 fragColor;
void main() { fragColor = vec4(v_color, 1.0); }`;

// A Lambert floor under a character that receives the sun's learned shadow: its grid vertices are receivers of the
// character's peak graph (the learned blockers; B, V dynamic: any receiver points), so each peak's visible fraction
// at a floor vertex comes from the same graph that shadows the character. Radiance per vertex:
//     albedo / pi (E_res(+z) + sum_p E_p max(l_p.z, 0) V_p)
// (E_res: the residual lighting's irradiance, unshadowed; the peaks off or absent: the whole lighting's, no shadow),
// tone-mapped as the character. A child of the character (its frame: z up, at the rest mesh's lowest point);
// update() after the character's update().
export class PRTFloor extends THREE.Mesh {
  constructor(character, { size = 4, resolution = 80, albedo = [0.5, 0.5, 0.5], height } = {}) {
    const m = character.m, r = m.camera.radius * character.gridScale;
    const g = new THREE.PlaneGeometry(size * r, size * r, resolution, resolution);
    g.setAttribute('color', new THREE.BufferAttribute(new Float32Array(3 * g.attributes.position.count), 3));
    super(g, new THREE.RawShaderMaterial({ glslVersion: THREE.GLSL3, vertexShader: 'precision highp float;\n' + FLOOR_VERTEX,
      fragmentShader: 'precision highp float;\n' + FLOOR_FRAGMENT, side: THREE.DoubleSide }));
    this.name = 'floor';
    this.character = character;
    this.albedo = albedo;
    const z = height === undefined ? character.floorHeight - 0.002 * m.camera.radius : height;
    this.position.set(m.camera.center[0], m.camera.center[1], z);
    this.frustumCulled = false;
    const n = g.attributes.position.count, p = g.attributes.position.array;
    this.points = new Float32Array(3 * n); // the vertices in the character's frame
    for (let i = 0; i < n; i++) {
      this.points[3 * i] = p[3 * i] + this.position.x;
      this.points[3 * i + 1] = p[3 * i + 1] + this.position.y;
      this.points[3 * i + 2] = z;
    }
    this.visibility = new Float32Array(n * MAX_PEAKS).fill(1); // (n, 4) peak p's visible fraction at vertex i
    this.irradiance = [0, 0, 0];
    character.add(this);
  }

  // each peak's visible fraction at the floor's vertices (the union of every instance's blockers), then the colours
  async update() {
    const c = this.character, n = this.points.length / 3;
    const pk = c.activePeaks();
    this.visibility.fill(1);
    if (pk && c.peakSession && !c.unshadowed) {
      const K = c.nChars, P = pk.directions.length;
      const pos = new Float32Array(K * 3 * n), nrm = new Float32Array(K * 3 * n);
      for (let k = 0; k < K; k++) {
        for (let i = 0; i < n; i++) { // instance k's receivers in its own frame (its grid offset removed)
          for (let e = 0; e < 3; e++) pos[3 * (k * n + i) + e] = this.points[3 * i + e] - c.offsets[3 * k + e];
          nrm[3 * (k * n + i) + 2] = 1;
        }
      }
      const v = await c.runPeaks(pos, nrm, c.skins, c.peakDirs, pk.angular_radii, K);
      for (let k = 0; k < K; k++) for (let i = 0; i < n; i++) for (let q = 0; q < P; q++) this.visibility[MAX_PEAKS * i + q] *= v[(k * n + i) * P + q];
    }
    this.shade();
  }

  // the floor's colours from its visibility under the character's lighting and tone map
  shade() {
    const c = this.character, m = c.m, u = c.material.uniforms;
    c.applyUniforms();
    const pk = c.activePeaks(), lt = m.lights[c.light];
    const lobes = pk || lt, nl = lobes.dirs.length;
    const dirs = Array.from({ length: nl }, (_, k) => u.u_lobeDir.value[k].toArray()); // turned into the frame
    this.irradiance = lobeIrradiance(dirs, lobes.coeffs, [0, 0, 1]);
    const nP = pk ? pk.directions.length : 0;
    const col = this.geometry.attributes.color.array, n = this.points.length / 3;
    const ex = u.u_exposure.value, wh = u.u_white.value, gm = u.u_gamma.value;
    for (let i = 0; i < n; i++) {
      for (let e = 0; e < 3; e++) {
        let E = this.irradiance[e];
        for (let p = 0; p < nP; p++) E += pk.powers[p][e] * Math.max(c.peakDirs[3 * p + 2], 0) * this.visibility[MAX_PEAKS * i + p];
        const x = Math.max(this.albedo[e] / Math.PI * E * ex, 0);
        col[3 * i + e] = Math.pow(Math.min(x * (1 + x / (wh * wh)) / (1 + x), 1), 1 / gm);
      }
    }
    this.geometry.attributes.color.needsUpdate = true;
  }
}
