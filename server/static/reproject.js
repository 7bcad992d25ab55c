// lumigraph web viewer: reprojection of received frames to the current camera (WebGL2), which
// hides the round trip while the next frame is on its way. Frames carry their z-depth and view
// in the header's depth extension (docs/protocol.md); each frame becomes a grid mesh, one vertex
// per pixel, unprojected with its depth (DESIGN §3) and projected into the current view.
// Triangles across depth discontinuities are cut; the previous frame, drawn behind, fills the
// holes this leaves where it saw the surface. Large frames get a coarser grid; their depth is
// first extended a grid step past the silhouette so edge cells survive, and each fragment keeps
// the coverage of its own source pixel, so silhouettes stay exact to the pixel. Plain JS, no
// build step.
"use strict";

window.LumigraphReproject = (() => {
  const DEPTH_MISS = -1;
  // A triangle is cut when its depths differ by more than this many pixel footprints: a surface
  // within ~3° of grazing (1 / tan 3° ≈ 19) or a depth discontinuity.
  const CUT_PIXELS = 20;
  // The previous frame is pushed this much further (relative depth) so the latest frame wins
  // wherever both have a surface, and the previous one only shows through the latest's holes.
  const PREVIOUS_DEPTH_BIAS = 0.02;
  // Grid cells per frame at most: a software GL draws a per-pixel grid of a full frame (about
  // 0.4 M cells, 2.4 M vertices) in hundreds of milliseconds, longer than the round trip it
  // hides; larger frames get a coarser grid (every STEP-th pixel; colour stays per pixel).
  const MAX_CELLS = 30000;

  const VERTEX = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_depth;
uniform ivec2 u_size;
uniform int u_step, u_quadsX;
uniform vec3 u_srcEye, u_srcRight, u_srcUp, u_srcForward;
uniform float u_srcFocal, u_maxRatio;
uniform vec3 u_dstEye, u_dstRight, u_dstUp, u_dstForward;
uniform vec2 u_dstScale, u_zRange;
uniform float u_bias;
out vec2 v_uv;
const ivec2 CORNER[6] = ivec2[6](ivec2(0, 0), ivec2(1, 0), ivec2(0, 1),
                                 ivec2(1, 0), ivec2(1, 1), ivec2(0, 1));
float depthAt(ivec2 p) { return texelFetch(u_depth, p, 0).r; }
void main() {
  int quad = gl_VertexID / 6, corner = gl_VertexID - quad * 6;
  ivec2 origin = ivec2(quad - (quad / u_quadsX) * u_quadsX, quad / u_quadsX) * u_step;
  ivec2 last = u_size - 1;
  int first = corner < 3 ? 0 : 3;
  float d0 = depthAt(min(origin + CORNER[first] * u_step, last));
  float d1 = depthAt(min(origin + CORNER[first + 1] * u_step, last));
  float d2 = depthAt(min(origin + CORNER[first + 2] * u_step, last));
  float lo = min(d0, min(d1, d2)), hi = max(d0, max(d1, d2));
  if (lo <= 0.0 || hi > lo * u_maxRatio) {
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // all three corners alike: the triangle is culled
    v_uv = vec2(0.0);
    return;
  }
  ivec2 px = min(origin + CORNER[corner] * u_step, last);
  float d = depthAt(px);
  vec2 size = vec2(u_size);
  // DESIGN §3: pixel (i, j) looks along x*right + y*up + forward, and its z-depth d scales that.
  float x = (float(px.x) + 0.5 - size.x * 0.5) / u_srcFocal;
  float y = -(float(px.y) + 0.5 - size.y * 0.5) / u_srcFocal;
  vec3 world = u_srcEye + d * (x * u_srcRight + y * u_srcUp + u_srcForward);
  vec3 q = world - u_dstEye;
  float cz = dot(q, u_dstForward);
  float zn = u_zRange.x, zf = u_zRange.y;
  float z = (2.0 * (cz * (1.0 + u_bias) - zn) / (zf - zn) - 1.0) * cz;
  gl_Position = vec4(dot(q, u_dstRight) * u_dstScale.x, dot(q, u_dstUp) * u_dstScale.y, z, cz);
  v_uv = (vec2(px) + 0.5) / size;
}`;
  const FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform sampler2D u_color;
in vec2 v_uv;
out vec4 color;
uniform highp sampler2D u_depth;
uniform ivec2 u_size;
void main() {
  // The grid may be coarser than the frame: keep only pixels the frame itself covered.
  ivec2 px = min(ivec2(v_uv * vec2(u_size)), u_size - 1);
  if (texelFetch(u_depth, px, 0).g < 0.5) discard;
  color = vec4(texture(u_color, v_uv).rgb, 1.0);
}`;

  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function norm(a) { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }

  // The orthonormal basis and focal length of a view (DESIGN §3).
  function basis(view) {
    const forward = norm(sub(view.target, view.eye));
    const right = norm(cross(forward, view.up));
    const up = cross(right, forward);
    const focal = (view.height / 2) / Math.tan((view.yfov_deg * Math.PI) / 360);
    return { eye: view.eye, forward, right, up, focal, width: view.width, height: view.height };
  }

  // Decodes a 16-bit grey PNG (the depth extension's codec) to z-depths: value q maps to
  // near + q / 65534 · (far - near), 65535 (no hit) to DEPTH_MISS. The browser's own decoders
  // reduce 16-bit PNGs to 8 bits, so the chunks are inflated and unfiltered here.
  async function decodePng16(bytes, near, far) {
    const be32 = (p) => ((bytes[p] << 24) | (bytes[p + 1] << 16) | (bytes[p + 2] << 8) | bytes[p + 3]) >>> 0;
    let p = 8, width = 0, height = 0;
    const idat = [];
    while (p + 8 <= bytes.length) {
      const len = be32(p);
      const type = String.fromCharCode(bytes[p + 4], bytes[p + 5], bytes[p + 6], bytes[p + 7]);
      const data = bytes.subarray(p + 8, p + 8 + len);
      if (type === "IHDR") {
        width = be32(p + 8); height = be32(p + 12);
        if (data[8] !== 16 || data[9] !== 0 || data[12] !== 0) throw new Error("depth is not a 16-bit grey PNG");
      } else if (type === "IDAT") {
        idat.push(data);
      } else if (type === "IEND") {
        break;
      }
      p += 12 + len;
    }
    const stream = new Blob(idat).stream().pipeThrough(new DecompressionStream("deflate"));
    const raw = new Uint8Array(await new Response(stream).arrayBuffer());
    const stride = width * 2;
    if (raw.length < height * (stride + 1)) throw new Error("depth PNG is truncated");
    const out = new Uint8Array(height * stride);
    for (let y = 0; y < height; y++) {
      const filter = raw[y * (stride + 1)];
      const src = y * (stride + 1) + 1, cur = y * stride, prev = cur - stride;
      for (let x = 0; x < stride; x++) {
        const a = x >= 2 ? out[cur + x - 2] : 0;
        const b = y > 0 ? out[prev + x] : 0;
        const c = x >= 2 && y > 0 ? out[prev + x - 2] : 0;
        let v = raw[src + x];
        if (filter === 1) v += a;
        else if (filter === 2) v += b;
        else if (filter === 3) v += (a + b) >> 1;
        else if (filter === 4) {
          const pa = Math.abs(b - c), pb = Math.abs(a - c), pc = Math.abs(a + b - 2 * c);
          v += pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
        }
        out[cur + x] = v & 255;
      }
    }
    const depth = new Float32Array(width * height);
    const step = (far - near) / 65534;
    for (let i = 0; i < depth.length; i++) {
      const q = (out[2 * i] << 8) | out[2 * i + 1];
      depth[i] = q === 65535 ? DEPTH_MISS : near + q * step;
    }
    return { width, height, depth };
  }

  // A WebGL2 warper on its own canvas; null where WebGL2 is missing.
  // The grid step of a frame of this size (every step-th pixel a vertex).
  function gridStep(width, height, maxCells) {
    return Math.max(1, Math.ceil(Math.sqrt(((width - 1) * (height - 1)) / maxCells)));
  }

  // Depth and coverage interleaved (RG): missed pixels within `step` pixels of a hit take the
  // depth of a neighbouring hit (grown one pixel per pass), so grid cells across the silhouette
  // keep their corners; coverage (G) stays that of the frame.
  function depthAndCoverage(decoded, step) {
    const { width, height } = decoded;
    let depth = decoded.depth;
    if (step > 1) {
      depth = depth.slice();
      for (let pass = 0; pass < step; pass++) {
        const prev = depth.slice();
        for (let y = 0; y < height; y++) {
          for (let x = 0; x < width; x++) {
            const i = y * width + x;
            if (prev[i] > 0) continue;
            const l = x > 0 ? prev[i - 1] : 0, r = x + 1 < width ? prev[i + 1] : 0;
            const u = y > 0 ? prev[i - width] : 0, d = y + 1 < height ? prev[i + width] : 0;
            const best = Math.max(l, r, u, d);
            if (best > 0) depth[i] = best;
          }
        }
      }
    }
    const rg = new Float32Array(2 * width * height);
    for (let i = 0; i < width * height; i++) {
      rg[2 * i] = depth[i];
      rg[2 * i + 1] = decoded.depth[i] > 0 ? 1 : 0;
    }
    return rg;
  }

  function createWarper() {
    const canvas = document.createElement("canvas");
    // preserveDrawingBuffer: the viewer copies the result onto its 2D canvas (and tests read it)
    // after the draw call returns.
    const gl = canvas.getContext("webgl2", { antialias: false, depth: true, preserveDrawingBuffer: true });
    if (!gl) return null;
    const compile = (type, text) => {
      const s = gl.createShader(type);
      gl.shaderSource(s, text);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      return s;
    };
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(program, compile(gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
    const uniforms = {};
    for (let i = 0; i < gl.getProgramParameter(program, gl.ACTIVE_UNIFORMS); i++) {
      const name = gl.getActiveUniform(program, i).name;
      uniforms[name] = gl.getUniformLocation(program, name);
    }
    const vao = gl.createVertexArray();
    // Newest first: [latest, previous].
    let sources = [];

    function texture() {
      const t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      return t;
    }

    // Keeps a frame (its colour bitmap, decoded depth and view) as the latest source.
    function push(bitmap, decoded, view) {
      if (decoded.width < 2 || decoded.height < 2) return;
      const recycled = sources.length === 2 ? sources.pop() : { color: texture(), depth: texture() };
      gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
      gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
      gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
      gl.bindTexture(gl.TEXTURE_2D, recycled.color);
      // Bilinear colour: the grid is per pixel, but a stretched triangle samples between pixels.
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, bitmap);
      gl.bindTexture(gl.TEXTURE_2D, recycled.depth);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      const rg = depthAndCoverage(decoded, gridStep(decoded.width, decoded.height, api.maxCells));
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RG32F, decoded.width, decoded.height, 0, gl.RG, gl.FLOAT, rg);
      let near = Infinity, far = 0;
      for (const d of decoded.depth) if (d > 0) { if (d < near) near = d; if (d > far) far = d; }
      recycled.view = basis({ ...view, width: decoded.width, height: decoded.height });
      recycled.near = near;
      recycled.far = far;
      sources.unshift(recycled);
    }

    function clear() { sources = []; }

    // Draws the kept frames as seen from `view` into the warper's canvas (view.width ×
    // view.height): RGB with alpha 1 where a frame covers the pixel, transparent elsewhere.
    // Returns false when there is nothing to draw.
    function draw(view) {
      const usable = sources.filter((s) => Number.isFinite(s.near));
      if (!usable.length) return false;
      if (canvas.width !== view.width || canvas.height !== view.height) {
        canvas.width = view.width; canvas.height = view.height;
      }
      const dst = basis(view);
      gl.viewport(0, 0, view.width, view.height);
      gl.clearColor(0, 0, 0, 0);
      gl.clearDepth(1);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.LESS);
      gl.useProgram(program);
      gl.bindVertexArray(vao);
      const near = Math.min(...usable.map((s) => s.near)), far = Math.max(...usable.map((s) => s.far));
      // Depth range of the destination: wide around the frames' depths (the camera may have
      // moved towards or away from them); points behind the near plane are clipped.
      gl.uniform2f(uniforms.u_zRange, near * 0.01, far * 100 + 1);
      gl.uniform3fv(uniforms.u_dstEye, dst.eye);
      gl.uniform3fv(uniforms.u_dstRight, dst.right);
      gl.uniform3fv(uniforms.u_dstUp, dst.up);
      gl.uniform3fv(uniforms.u_dstForward, dst.forward);
      gl.uniform2f(uniforms.u_dstScale, dst.focal / (view.width / 2), dst.focal / (view.height / 2));
      gl.uniform1i(uniforms.u_depth, 0);
      gl.uniform1i(uniforms.u_color, 1);
      usable.forEach((s, index) => {
        const v = s.view;
        gl.activeTexture(gl.TEXTURE0);
        gl.bindTexture(gl.TEXTURE_2D, s.depth);
        gl.activeTexture(gl.TEXTURE1);
        gl.bindTexture(gl.TEXTURE_2D, s.color);
        gl.uniform2i(uniforms.u_size, v.width, v.height);
        gl.uniform3fv(uniforms.u_srcEye, v.eye);
        gl.uniform3fv(uniforms.u_srcRight, v.right);
        gl.uniform3fv(uniforms.u_srcUp, v.up);
        gl.uniform3fv(uniforms.u_srcForward, v.forward);
        gl.uniform1f(uniforms.u_srcFocal, v.focal);
        const step = gridStep(v.width, v.height, api.maxCells);
        const quadsX = Math.ceil((v.width - 1) / step), quadsY = Math.ceil((v.height - 1) / step);
        gl.uniform1i(uniforms.u_step, step);
        gl.uniform1i(uniforms.u_quadsX, quadsX);
        gl.uniform1f(uniforms.u_maxRatio, 1 + (CUT_PIXELS * step) / v.focal);
        gl.uniform1f(uniforms.u_bias, index === 0 ? 0 : PREVIOUS_DEPTH_BIAS);
        gl.drawArrays(gl.TRIANGLES, 0, 6 * quadsX * quadsY);
      });
      return true;
    }

    const api = { canvas, gl, push, draw, clear, sourceCount: () => sources.length, maxCells: MAX_CELLS };
    return api;
  }

  return { createWarper, decodePng16, basis };
})();
