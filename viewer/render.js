// Drawing nodes with WebGL2: one vertex array per resident node (positions relative to the
// streamer's local origin, normals, colours), lit as strata's software renderer lights them
// (src/render.rs: a headlight along the view direction, 18 % ambient, per vertex; faces without
// normals lit flat), so the two can be compared pixel by pixel.

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

const VERTEX = `#version 300 es
uniform mat4 viewProjection;
uniform vec3 light;
uniform vec4 tint;
uniform bool useColors;
uniform bool hasNormals;
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec4 color;
out vec3 place;
out vec4 shade;
flat out int lit;
void main() {
  place = position;
  vec4 base = useColors ? color : tint;
  float l = 0.18 + 0.82 * max(dot(normalize(normal), light), 0.0);
  shade = hasNormals ? vec4(base.rgb * l, base.a) : base;
  lit = hasNormals ? 1 : 0;
  gl_Position = viewProjection * vec4(position, 1.0);
}`;

const FRAGMENT = `#version 300 es
precision highp float;
uniform vec3 light;
in vec3 place;
in vec4 shade;
flat in int lit;
out vec4 outColor;
void main() {
  if (lit == 1) {
    outColor = vec4(shade.rgb, 1.0);
  } else {
    vec3 n = normalize(cross(dFdx(place), dFdy(place)));
    outColor = vec4(shade.rgb * (0.18 + 0.82 * abs(dot(n, light))), 1.0);
  }
}`;

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
    this.u = Object.fromEntries(['viewProjection', 'light', 'tint', 'useColors', 'hasNormals'].map((n) => [n, gl.getUniformLocation(p, n)]));
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
    const index = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, index);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, geometry.indices, gl.STATIC_DRAW);
    buffers.push(index);
    gl.bindVertexArray(null);
    return { vao, buffers, normals: !!geometry.normals, colors: !!geometry.colors, ranges: geometry.materialRanges, count: geometry.indices.length };
  }

  release(handle) {
    if (!handle) return;
    const gl = this.gl;
    gl.deleteVertexArray(handle.vao);
    for (const b of handle.buffers) gl.deleteBuffer(b);
  }

  /**
   * Draw `nodes` (`[{id, handle, level}]`) seen by `camera`, positions relative to `origin`.
   * `mode`: 'plain' | 'material' | 'level' | 'node'; `materials` from the skeleton.
   */
  draw(camera, origin, nodes, mode, materials) {
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
    for (const { id, handle, level } of nodes) {
      if (!handle) continue;
      gl.bindVertexArray(handle.vao);
      gl.uniform1i(this.u.hasNormals, handle.normals ? 1 : 0);
      if (!handle.normals) gl.vertexAttrib3f(1, 0, 0, 1);
      const byMaterial = mode === 'material';
      gl.uniform1i(this.u.useColors, byMaterial && handle.colors ? 1 : 0);
      if (!handle.colors) gl.vertexAttrib4f(2, 1, 1, 1, 1);
      if (byMaterial && !handle.colors) {
        for (const [m, first, count] of handle.ranges) {
          const c = materials[m]?.baseColor ?? [0.8, 0.8, 0.8, 1];
          gl.uniform4f(this.u.tint, c[0], c[1], c[2], 1);
          gl.drawElements(gl.TRIANGLES, count, gl.UNSIGNED_INT, first * 4);
        }
        continue;
      }
      const c = mode === 'level' ? palette(level) : mode === 'node' ? palette(id) : PLAIN;
      gl.uniform4f(this.u.tint, c[0] / 255, c[1] / 255, c[2] / 255, 1);
      gl.drawElements(gl.TRIANGLES, handle.count, gl.UNSIGNED_INT, 0);
    }
    gl.bindVertexArray(null);
  }
}
