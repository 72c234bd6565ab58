// Drawing nodes with WebGL2: one vertex array per resident node (positions relative to the
// streamer's local origin, normals, colours, UVs), lit as strata's software renderer lights them
// (src/render.rs: a headlight along the view direction, 18 % ambient, per vertex; faces without
// normals lit flat), so the two can be compared pixel by pixel. Textured materials sample their
// base color image (one texture per resident image level, mipmapped) as strata render does:
// texel × the base color's sRGB bytes × light, all in the image's sRGB values.

import { multiply, sub } from './camera.js';

export const BACKGROUND = [28, 30, 36];
export const PLAIN = [200, 200, 200];

/** strata's colour for an id (src/render.rs `palette`): golden-ratio hues, varied saturation and value. */
export function palette(id) {
  const hue = ((id * 0.618033988749895) % 1) * 6;
  const saturation = [0.65, 0.45, 0.8][Math.floor(id / 7) % 3];
  const value = [0.95, 0.8][Math.floor(id / 3) % 2];
  const c = value * saturation;
  const x = c * (1 - Math.abs((hue % 2) - 1));
  const [r, g, b] = [[c, x, 0], [x, c, 0], [0, c, x], [0, x, c], [x, 0, c], [c, 0, x]][Math.min(Math.floor(hue), 5)];
  const m = value - c;
  return [r + m, g + m, b + m].map((v) => Math.round(v * 255));
}

/** The sRGB value (0..1, rounded to a byte as src/texture/draw.rs `srgb_color`) of a linear colour channel. */
export function srgb(c) {
  const x = Math.min(Math.max(c, 0), 1);
  const e = x <= 0.0031308 ? x * 12.92 : 1.055 * x ** (1 / 2.4) - 0.055;
  return Math.floor(e * 255 + 0.5) / 255;
}

const VERTEX = `#version 300 es
uniform mat4 viewProjection;
uniform vec3 light;
uniform vec4 tint;
uniform bool useColors;
uniform bool hasNormals;
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec4 color;
layout(location = 3) in vec2 uv;
out vec3 place;
out vec4 shade;
out vec2 texcoord;
flat out int lit;
void main() {
  place = position;
  texcoord = uv;
  vec4 base = useColors ? color : tint;
  float l = 0.18 + 0.82 * max(dot(normalize(normal), light), 0.0);
  shade = hasNormals ? vec4(base.rgb * l, base.a) : base;
  lit = hasNormals ? 1 : 0;
  gl_Position = viewProjection * vec4(position, 1.0);
}`;

const FRAGMENT = `#version 300 es
precision highp float;
uniform vec3 light;
uniform bool textured;
uniform sampler2D baseColorMap;
in vec3 place;
in vec4 shade;
in vec2 texcoord;
flat in int lit;
out vec4 outColor;
void main() {
  vec3 c = shade.rgb;
  if (lit != 1) {
    vec3 n = normalize(cross(dFdx(place), dFdy(place)));
    c *= 0.18 + 0.82 * abs(dot(n, light));
  }
  if (textured) c *= texture(baseColorMap, texcoord).rgb;
  outColor = vec4(c, 1.0);
}`;

/** WebGL wrap modes of the format's codes (spec §7.5: 0 repeat, 1 clamp to edge, 2 mirrored repeat). */
const WRAPS = ['REPEAT', 'CLAMP_TO_EDGE', 'MIRRORED_REPEAT'];

function compile(gl, type, text) {
  const s = gl.createShader(type);
  gl.shaderSource(s, text);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
  return s;
}

export class Renderer {
  constructor(canvas) {
    const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
    if (!gl) throw new Error('This browser has no WebGL2: the viewer needs it.');
    this.gl = gl;
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`shader program: ${gl.getProgramInfoLog(p)}`);
    this.program = p;
    const uniforms = ['viewProjection', 'light', 'tint', 'useColors', 'hasNormals', 'textured', 'baseColorMap'];
    this.u = Object.fromEntries(uniforms.map((n) => [n, gl.getUniformLocation(p, n)]));
    /** One sampler per pair of wrap modes, made when first used. */
    this.samplers = new Map();
    /** Image levels decoded so far: `{mime, width, height, ms}`, for tests and the console. */
    this.decoded = [];
  }

  /**
   * Decode an image level's file (PNG or JPEG bytes of media type `mime`) and upload it as a
   * mipmapped RGBA8 texture, its rows as the file has them (UV (0, 0) is the image's top-left
   * corner, as the texture's first row is), pixels as stored: no colour-space conversion nor
   * premultiplied alpha. Resolves to its handle.
   */
  async uploadImage(bytes, mime) {
    const t0 = performance.now();
    const blob = new Blob([bytes], { type: mime });
    let source;
    if (typeof createImageBitmap === 'function') {
      source = await createImageBitmap(blob, { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
    } else {
      source = new Image();
      const url = URL.createObjectURL(blob);
      try {
        source.src = url;
        await source.decode();
      } finally {
        URL.revokeObjectURL(url);
      }
    }
    const gl = this.gl;
    const texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, texture);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
    gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, source);
    gl.generateMipmap(gl.TEXTURE_2D);
    gl.bindTexture(gl.TEXTURE_2D, null);
    const width = source.width, height = source.height;
    source.close?.();
    this.decoded.push({ mime, width, height, ms: performance.now() - t0 });
    return { texture, width, height };
  }

  releaseImage(handle) {
    if (handle) this.gl.deleteTexture(handle.texture);
  }

  /** The sampler for wrap modes [s, t]: linear, trilinear between mipmap levels. */
  sampler([ws, wt]) {
    const key = 3 * ws + wt;
    let s = this.samplers.get(key);
    if (!s) {
      const gl = this.gl;
      s = gl.createSampler();
      gl.samplerParameteri(s, gl.TEXTURE_MIN_FILTER, gl.LINEAR_MIPMAP_LINEAR);
      gl.samplerParameteri(s, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.samplerParameteri(s, gl.TEXTURE_WRAP_S, gl[WRAPS[ws] ?? 'REPEAT']);
      gl.samplerParameteri(s, gl.TEXTURE_WRAP_T, gl[WRAPS[wt] ?? 'REPEAT']);
      this.samplers.set(key, s);
    }
    return s;
  }

  /** Upload a node's geometry (local positions); returns its handle. */
  upload(geometry) {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const buffers = [];
    const attribute = (location, data, size, type, normalized) => {
      const b = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, size, type, normalized, 0, 0);
      buffers.push(b);
    };
    attribute(0, geometry.local ?? geometry.positions, 3, gl.FLOAT, false);
    if (geometry.normals) attribute(1, geometry.normals, 3, gl.FLOAT, false);
    if (geometry.colors) attribute(2, geometry.colors, 4, gl.UNSIGNED_BYTE, true);
    if (geometry.uvs) attribute(3, geometry.uvs, 2, gl.FLOAT, false);
    const index = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, index);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, geometry.indices, gl.STATIC_DRAW);
    buffers.push(index);
    gl.bindVertexArray(null);
    return { vao, buffers, normals: !!geometry.normals, colors: !!geometry.colors, uvs: !!geometry.uvs, ranges: geometry.materialRanges, count: geometry.indices.length };
  }

  release(handle) {
    if (!handle) return;
    const gl = this.gl;
    gl.deleteVertexArray(handle.vao);
    for (const b of handle.buffers) gl.deleteBuffer(b);
  }

  /**
   * Draw `nodes` (`[{id, handle, level, seam}]`) seen by `camera`, positions relative to `origin`;
   * an entry with `seam` set holds the seams between levels, drawn plain whatever the mode.
   * `mode`: 'plain' | 'material' | 'level' | 'node'; `materials` from the skeleton; `imageOf(image)`
   * the texture handle of an image's level to draw, or null (the material is drawn untextured).
   */
  draw(camera, origin, nodes, mode, materials, imageOf = () => null) {
    const gl = this.gl;
    const { width, height } = gl.canvas;
    gl.viewport(0, 0, width, height);
    gl.clearColor(BACKGROUND[0] / 255, BACKGROUND[1] / 255, BACKGROUND[2] / 255, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.program);
    const local = Object.assign(Object.create(Object.getPrototypeOf(camera)), camera, { eye: sub(camera.eye, origin), target: sub(camera.target, origin) });
    gl.uniformMatrix4fv(this.u.viewProjection, false, new Float32Array(multiply(local.projectionMatrix(), local.view())));
    const f = camera.forward();
    gl.uniform3f(this.u.light, -f[0], -f[1], -f[2]);
    gl.uniform1i(this.u.baseColorMap, 0);
    gl.activeTexture(gl.TEXTURE0);
    let textured = false;
    const texture = (tex, wrap) => {
      if (tex) {
        gl.bindTexture(gl.TEXTURE_2D, tex.texture);
        gl.bindSampler(0, this.sampler(wrap));
      }
      if (!!tex !== textured) gl.uniform1i(this.u.textured, tex ? 1 : 0);
      textured = !!tex;
    };
    gl.uniform1i(this.u.textured, 0);
    for (const { id, handle, level, seam } of nodes) {
      if (!handle) continue;
      gl.bindVertexArray(handle.vao);
      gl.uniform1i(this.u.hasNormals, handle.normals ? 1 : 0);
      if (!handle.normals) gl.vertexAttrib3f(1, 0, 0, 1);
      if (!handle.uvs) gl.vertexAttrib2f(3, 0, 0);
      // The seams between levels (`seam`) belong to no node and no material: drawn plain.
      const byMaterial = mode === 'material' && !seam;
      gl.uniform1i(this.u.useColors, byMaterial && handle.colors ? 1 : 0);
      if (!handle.colors) gl.vertexAttrib4f(2, 1, 1, 1, 1);
      if (byMaterial) {
        // Per material range: vertex colours where the node has them, else the material's colour;
        // times the base color image where the material maps one and it is resident.
        for (const [m, first, count] of handle.ranges) {
          const mat = materials[m];
          const slot = handle.uvs ? mat?.maps?.baseColor : null;
          const tex = slot ? imageOf(slot.image) : null;
          texture(tex, slot?.wrap);
          const c = mat?.baseColor ?? [0.8, 0.8, 0.8, 1];
          if (tex) gl.uniform4f(this.u.tint, srgb(c[0]), srgb(c[1]), srgb(c[2]), 1);
          else gl.uniform4f(this.u.tint, c[0], c[1], c[2], 1);
          gl.drawElements(gl.TRIANGLES, count, gl.UNSIGNED_INT, first * 4);
        }
        continue;
      }
      texture(null);
      const c = seam ? PLAIN : mode === 'level' ? palette(level) : mode === 'node' ? palette(id) : PLAIN;
      gl.uniform4f(this.u.tint, c[0] / 255, c[1] / 255, c[2] / 255, 1);
      gl.drawElements(gl.TRIANGLES, handle.count, gl.UNSIGNED_INT, 0);
    }
    gl.bindVertexArray(null);
    gl.bindSampler(0, null);
  }
}
