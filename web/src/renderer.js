// WebGL2 splat renderer with the semantics of gscodec's CPU renderer (DESIGN §3,
// decoder/src/math.rs, decoder/src/render/cpu.rs): per Gaussian the EWA projection with the
// 1.3·tan(half-FOV) Jacobian clamp and +0.3 px² dilation, the conic, the 3σ radius and the 16×16
// tile rectangle of the reference rasterizer's getRect, the SH colour (+0.5, clamped at 0, no upper
// clamp); per pixel alpha = min(0.99, o·exp(power)), skipped below 1/255. Gaussians are drawn back to
// front (sorted by camera depth in the worker) with premultiplied "over" blending, which composites
// like the CPU's front-to-back loop; the one thing not reproduced is its stop once transmittance
// falls below 1e-4. Colours accumulate in an RGBA32F target (RGBA16F without float blending), so
// nothing is clamped before the final copy to the canvas, as the CPU renderer clamps only when it
// writes the PNG.

const SPLAT_VS = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;

uniform sampler2D u_splats;   // 3 texels per Gaussian (see worker.js pack)
uniform sampler2D u_sh;       // u_shStride texels per Gaussian
uniform int u_texWidth;
uniform int u_shStride;
uniform int u_degree;         // SH degree evaluated (<= the scene's)
uniform mat3 u_R;             // world -> camera rotation
uniform vec3 u_t;
uniform vec2 u_focal;         // fx, fy
uniform vec2 u_principal;     // cx, cy
uniform vec2 u_size;          // width, height in pixels
uniform float u_znear;
uniform vec3 u_center;        // camera centre in world space

in uint a_index;

flat out vec2 v_mean;
flat out vec3 v_conic;
flat out float v_opacity;
flat out vec3 v_color;

vec4 fetch(sampler2D tex, int i) {
  return texelFetch(tex, ivec2(i % u_texWidth, i / u_texWidth), 0);
}

void cull() {
  gl_Position = vec4(0.0, 0.0, 2.0, 1.0); // outside the clip volume
}

const float SH_C0 = 0.28209479;
const float SH_C1 = 0.48860252;
const float SH_C2[5] = float[5](1.0925484, -1.0925484, 0.31539157, -1.0925484, 0.5462742);
const float SH_C3[7] = float[7](-0.5900436, 2.8906114, -0.4570458, 0.37317634, -0.4570458, 1.4453057, -0.5900436);

void main() {
  int i = int(a_index);
  vec4 t0 = fetch(u_splats, i * 3);
  vec4 t1 = fetch(u_splats, i * 3 + 1);
  vec4 t2 = fetch(u_splats, i * 3 + 2);
  vec3 pos = t0.xyz;
  float opacity = t0.w;
  vec3 t = u_R * pos + u_t;
  if (!(t.z > u_znear)) { cull(); return; }
  mat3 cov3d = mat3(t1.x, t1.y, t1.z, t1.y, t1.w, t2.x, t1.z, t2.x, t2.y);

  // EWA projection (math::project_cov2d).
  vec2 lim = 1.3 * u_size / (2.0 * u_focal);
  float tx = clamp(t.x / t.z, -lim.x, lim.x) * t.z;
  float ty = clamp(t.y / t.z, -lim.y, lim.y) * t.z;
  float iz = 1.0 / t.z;
  float iz2 = 1.0 / (t.z * t.z);
  vec3 j0 = vec3(u_focal.x * iz, 0.0, -u_focal.x * tx * iz2);
  vec3 j1 = vec3(0.0, u_focal.y * iz, -u_focal.y * ty * iz2);
  mat3 wt = transpose(u_R);
  vec3 r0 = wt * j0;
  vec3 r1 = wt * j1;
  float a = dot(r0, cov3d * r0) + 0.3;
  float b = dot(r0, cov3d * r1);
  float c = dot(r1, cov3d * r1) + 0.3;

  // Conic and 3σ radius (math::conic_and_radius).
  float det = a * c - b * b;
  if (!(det > 0.0)) { cull(); return; }
  float inv = 1.0 / det;
  float mid = 0.5 * (a + c);
  float lambda1 = mid + sqrt(max(mid * mid - det, 0.1));
  float radius = ceil(3.0 * sqrt(lambda1));
  vec2 mean = u_focal * t.xy / t.z + u_principal;

  // Tiles touched (math::tile_rect, pixel-index coordinates), as pixel bounds.
  vec2 grid = ceil(u_size / 16.0);
  vec2 p = mean - 0.5;
  vec2 tlo = floor(clamp((p - radius) / 16.0, vec2(0.0), grid));
  vec2 thi = floor(clamp((p + radius + 15.0) / 16.0, vec2(0.0), grid));
  if (thi.x <= tlo.x || thi.y <= tlo.y) { cull(); return; }
  // Alpha reaches 1/255 only within sqrt(2 λ ln(255 o)) of the mean (λ >= the largest
  // eigenvalue), so the quad is that disc's box within the tile rectangle: no pixel the CPU
  // renderer would blend is left out.
  if (!(opacity * 255.0 > 1.0)) { cull(); return; }
  float reach = sqrt(2.0 * lambda1 * log(255.0 * opacity)) + 1.0;
  vec2 lo = max(tlo * 16.0, floor(mean - reach));
  vec2 hi = min(min(thi * 16.0, u_size), ceil(mean + reach));
  if (hi.x <= lo.x || hi.y <= lo.y) { cull(); return; }

  // SH colour (math::sh_color) for the view direction from the camera centre.
  vec3 d = pos - u_center;
  vec3 dir = length(d) > 0.0 ? normalize(d) : vec3(0.0, 0.0, 1.0);
  float basis[16];
  basis[0] = SH_C0;
  float x = dir.x, y = dir.y, z = dir.z;
  basis[1] = -SH_C1 * y; basis[2] = SH_C1 * z; basis[3] = -SH_C1 * x;
  float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  basis[4] = SH_C2[0] * xy; basis[5] = SH_C2[1] * yz; basis[6] = SH_C2[2] * (2.0 * zz - xx - yy);
  basis[7] = SH_C2[3] * xz; basis[8] = SH_C2[4] * (xx - yy);
  basis[9] = SH_C3[0] * y * (3.0 * xx - yy); basis[10] = SH_C3[1] * xy * z;
  basis[11] = SH_C3[2] * y * (4.0 * zz - xx - yy); basis[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
  basis[13] = SH_C3[4] * x * (4.0 * zz - xx - yy); basis[14] = SH_C3[5] * z * (xx - yy);
  basis[15] = SH_C3[6] * x * (xx - 3.0 * yy);
  float coef[48];
  for (int j = 0; j < 12; j++) {
    if (j >= u_shStride) break;
    vec4 v = fetch(u_sh, i * u_shStride + j);
    coef[4 * j] = v.x; coef[4 * j + 1] = v.y; coef[4 * j + 2] = v.z; coef[4 * j + 3] = v.w;
  }
  int coeffs = (u_degree + 1) * (u_degree + 1);
  vec3 color = vec3(0.5);
  for (int k = 0; k < 16; k++) {
    if (k >= coeffs) break;
    color += basis[k] * vec3(coef[3 * k], coef[3 * k + 1], coef[3 * k + 2]);
  }

  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));
  vec2 pixel = mix(lo, hi, corner);
  v_mean = mean;
  v_conic = vec3(c * inv, -b * inv, a * inv);
  v_opacity = opacity;
  v_color = max(color, 0.0);
  gl_Position = vec4(2.0 * pixel.x / u_size.x - 1.0, 1.0 - 2.0 * pixel.y / u_size.y, 0.0, 1.0);
}`;

const SPLAT_FS = `#version 300 es
precision highp float;

uniform vec2 u_size;
flat in vec2 v_mean;
flat in vec3 v_conic;
flat in float v_opacity;
flat in vec3 v_color;
out vec4 out_color;

void main() {
  // Pixel centre in image coordinates (y down); the offset as the CPU's mean - pixel centre.
  vec2 d = v_mean - vec2(gl_FragCoord.x, u_size.y - gl_FragCoord.y);
  float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;
  if (power > 0.0) discard;
  float alpha = min(0.99, v_opacity * exp(power));
  if (alpha < 1.0 / 255.0) discard;
  out_color = vec4(v_color * alpha, alpha);
}`;

const BLIT_VS = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}`;

const BLIT_FS = `#version 300 es
precision highp float;
precision highp sampler2D;
uniform sampler2D u_image;
out vec4 out_color;
void main() {
  out_color = vec4(clamp(texelFetch(u_image, ivec2(gl_FragCoord.xy), 0).rgb, 0.0, 1.0), 1.0);
}`;

function compile(gl, vs, fs) {
  const program = gl.createProgram();
  for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
    gl.attachShader(program, s);
  }
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(program)}`);
  const uniforms = {};
  for (let k = 0; k < gl.getProgramParameter(program, gl.ACTIVE_UNIFORMS); k++) {
    const name = gl.getActiveUniform(program, k).name;
    uniforms[name] = gl.getUniformLocation(program, name);
  }
  return { program, uniforms };
}

export class SplatRenderer {
  constructor(canvas) {
    const gl = canvas.getContext('webgl2', { antialias: false, alpha: false, depth: false, preserveDrawingBuffer: true, premultipliedAlpha: false });
    if (!gl) throw new Error('WebGL2 is not available');
    this.gl = gl;
    this.canvas = canvas;
    const colorFloat = gl.getExtension('EXT_color_buffer_float');
    const floatBlend = gl.getExtension('EXT_float_blend');
    this.target = colorFloat ? (floatBlend ? 'rgba32f' : 'rgba16f') : 'canvas';
    this.splat = compile(gl, SPLAT_VS, SPLAT_FS);
    this.blit = compile(gl, BLIT_VS, BLIT_FS);
    this.maxTexture = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    this.vao = gl.createVertexArray();
    this.orderBuffer = gl.createBuffer();
    gl.bindVertexArray(this.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.orderBuffer);
    const loc = gl.getAttribLocation(this.splat.program, 'a_index');
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribIPointer(loc, 1, gl.UNSIGNED_INT, 0, 0);
    gl.vertexAttribDivisor(loc, 1);
    gl.bindVertexArray(null);
    this.visible = 0;
    this.scene = null;
  }

  /** Uploads a packed scene (worker.js pack). */
  setScene(gpu) {
    const gl = this.gl;
    if (Math.max(gpu.splatRows, gpu.shRows) > this.maxTexture) throw new Error(`scene too large for this GPU's ${this.maxTexture}-texel textures`);
    const upload = (old, data, rows) => {
      if (old) gl.deleteTexture(old);
      const tex = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, gpu.width, rows, 0, gl.RGBA, gl.FLOAT, data);
      return tex;
    };
    this.splatTex = upload(this.splatTex, gpu.splats, gpu.splatRows);
    this.shTex = upload(this.shTex, gpu.sh, gpu.shRows);
    this.scene = { count: gpu.count, shDegree: gpu.shDegree, width: gpu.width, shStride: gpu.shStride };
    this.visible = 0;
  }

  /** The draw order (indices, back to front) for the current camera. */
  setOrder(order) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.orderBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, order, gl.DYNAMIC_DRAW);
    this.visible = order.length;
  }

  /** The accumulation target at the canvas size (none when drawing straight to the canvas). */
  framebuffer(width, height) {
    const gl = this.gl;
    if (this.target === 'canvas') return null;
    if (this.fb && this.fbSize[0] === width && this.fbSize[1] === height) return this.fb;
    if (this.fb) {
      gl.deleteFramebuffer(this.fb);
      gl.deleteTexture(this.fbTex);
    }
    this.fbTex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.fbTex);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texStorage2D(gl.TEXTURE_2D, 1, this.target === 'rgba32f' ? gl.RGBA32F : gl.RGBA16F, width, height);
    this.fb = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, this.fbTex, 0);
    this.fbSize = [width, height];
    return this.fb;
  }

  /** Draws the scene from `cam` (camera.js) over `background` (RGB in [0, 1]). */
  render(cam, background = [0, 0, 0], maxShDegree = 3) {
    const gl = this.gl;
    const { width, height } = cam;
    if (this.canvas.width !== width) this.canvas.width = width;
    if (this.canvas.height !== height) this.canvas.height = height;
    const fb = this.framebuffer(width, height);
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.viewport(0, 0, width, height);
    gl.clearColor(background[0], background[1], background[2], 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    if (this.scene && this.visible > 0) {
      const { program, uniforms: u } = this.splat;
      gl.useProgram(program);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, this.splatTex);
      gl.uniform1i(u.u_splats, 0);
      gl.activeTexture(gl.TEXTURE1);
      gl.bindTexture(gl.TEXTURE_2D, this.shTex);
      gl.uniform1i(u.u_sh, 1);
      gl.uniform1i(u.u_texWidth, this.scene.width);
      gl.uniform1i(u.u_shStride, this.scene.shStride);
      gl.uniform1i(u.u_degree, Math.min(maxShDegree, this.scene.shDegree));
      gl.uniformMatrix3fv(u.u_R, true, cam.R);
      gl.uniform3fv(u.u_t, cam.t);
      gl.uniform2f(u.u_focal, cam.fx, cam.fy);
      gl.uniform2f(u.u_principal, cam.cx, cam.cy);
      gl.uniform2f(u.u_size, width, height);
      gl.uniform1f(u.u_znear, cam.znear);
      const { R, t } = cam;
      gl.uniform3f(u.u_center, -(R[0] * t[0] + R[3] * t[1] + R[6] * t[2]), -(R[1] * t[0] + R[4] * t[1] + R[7] * t[2]), -(R[2] * t[0] + R[5] * t[1] + R[8] * t[2]));
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
      gl.bindVertexArray(this.vao);
      gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, this.visible);
      gl.bindVertexArray(null);
      gl.disable(gl.BLEND);
    }
    if (fb) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.useProgram(this.blit.program);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, this.fbTex);
      gl.uniform1i(this.blit.uniforms.u_image, 0);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
  }
}
