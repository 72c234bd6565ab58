// A viewer's camera, as strata's (src/camera.rs) and format-spec/selection.md define it: eye,
// target, up, a perspective (vertical field of view) or orthographic (visible height) projection,
// a viewport in pixels, near and far. Matrices are column-major arrays of 16 numbers (f64), the
// layout WebGL's uniformMatrix4fv takes; view and projection follow OpenGL's right-handed
// convention (clip z in [-w, w]), as glam's look_at_mat4 and proj::opengl do.

export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const length = (a) => Math.sqrt(dot(a, a));

/** The unit vector along `a`, or null when it has no direction. */
export function unit(a) {
  const l = length(a);
  return l > 0 && Number.isFinite(l) ? scale(a, 1 / l) : null;
}

/** The angle between two directions, in radians: atan2(|a × b|, a·b). */
export const angle = (a, b) => Math.atan2(length(cross(a, b)), dot(a, b));

/** Column-major 4×4 product a·b. */
export function multiply(a, b) {
  const m = new Float64Array(16);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      m[c * 4 + r] = s;
    }
  }
  return m;
}

export class Camera {
  /**
   * @param {object} c `{eye, target, up, projection: {perspective: {fov_y}} | {orthographic: {height}},
   *   width, height, near, far}`, the JSON form of `strata stream --print-front` and fronts.json.
   */
  constructor(c) {
    this.eye = [...c.eye];
    this.target = [...c.target];
    this.up = [...c.up];
    this.projection = c.projection.perspective
      ? { perspective: { fov_y: c.projection.perspective.fov_y } }
      : { orthographic: { height: c.projection.orthographic.height } };
    this.width = c.width;
    this.height = c.height;
    this.near = c.near;
    this.far = c.far;
  }

  /** A perspective camera framing the sphere (center, radius) from direction `from`, as strata's `Camera::framing`. */
  static framing(center, radius, from, fovY, width, height) {
    const dir = unit(from) ?? [0, 0, 1];
    const distance = radius / Math.max(Math.sin(0.5 * fovY), 1e-3);
    const c = cross(dir, [0, 1, 0]);
    const up = dot(c, c) < 1e-6 ? [0, 0, 1] : [0, 1, 0];
    return new Camera({
      eye: add(center, scale(dir, distance)),
      target: [...center],
      up,
      projection: { perspective: { fov_y: fovY } },
      width,
      height,
      near: Math.max(distance - radius, distance * 1e-3),
      far: distance + radius,
    });
  }

  toJSON() {
    return {
      eye: this.eye, target: this.target, up: this.up, projection: this.projection,
      width: this.width, height: this.height, near: this.near, far: this.far,
    };
  }

  get perspective() {
    return this.projection.perspective !== undefined;
  }

  aspect() {
    return Math.max(this.width, 1) / Math.max(this.height, 1);
  }

  /** Unit direction the camera looks along. */
  forward() {
    return unit(sub(this.target, this.eye)) ?? [0, 0, -1];
  }

  view() {
    const f = unit(sub(this.target, this.eye)) ?? [0, 0, -1];
    const s = unit(cross(f, this.up)) ?? [1, 0, 0];
    const u = cross(s, f);
    const e = this.eye;
    return Float64Array.of(
      s[0], u[0], -f[0], 0,
      s[1], u[1], -f[1], 0,
      s[2], u[2], -f[2], 0,
      -dot(s, e), -dot(u, e), dot(f, e), 1,
    );
  }

  projectionMatrix() {
    const { near: n, far: f } = this;
    if (this.perspective) {
      const t = 1 / Math.tan(0.5 * this.projection.perspective.fov_y);
      return Float64Array.of(t / this.aspect(), 0, 0, 0, 0, t, 0, 0, 0, 0, (f + n) / (n - f), -1, 0, 0, (2 * f * n) / (n - f), 0);
    }
    const h = 0.5 * this.projection.orthographic.height;
    const w = h * this.aspect();
    return Float64Array.of(1 / w, 0, 0, 0, 0, 1 / h, 0, 0, 0, 0, -2 / (f - n), 0, 0, 0, -(f + n) / (f - n), 1);
  }

  /** Model space to clip space. */
  viewProjection() {
    return multiply(this.projectionMatrix(), this.view());
  }

  /** The six frustum planes [nx, ny, nz, d], normals inward, each row₃ ± rowᵢ normalized by its xyz length. */
  frustum() {
    const m = this.viewProjection();
    const row = (r) => [m[r], m[4 + r], m[8 + r], m[12 + r]];
    const r3 = row(3);
    const planes = [];
    for (const i of [0, 1, 2]) {
      for (const sign of [1, -1]) {
        const ri = row(i);
        const v = r3.map((x, k) => x + sign * ri[k]);
        const len = Math.max(Math.hypot(v[0], v[1], v[2]), Number.MIN_VALUE);
        planes.push([v[0] / len, v[1] / len, v[2] / len, v[3] / len]);
      }
    }
    return planes;
  }

  /** Pixels per model unit at `distance` from the eye (at least `near`). */
  pixelsPerUnit(distance) {
    if (this.perspective) {
      return this.height / (2 * Math.tan(0.5 * this.projection.perspective.fov_y) * Math.max(distance, this.near));
    }
    return this.height / Math.max(this.projection.orthographic.height, Number.MIN_VALUE);
  }

  /** Pixels a model-space `error` spans for anything in the sphere (center, radius), at its nearest point. */
  projectedError(error, center, radius) {
    return error * this.pixelsPerUnit(Math.max(length(sub(this.eye, center)) - radius, 0));
  }
}
