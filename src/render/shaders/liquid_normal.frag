// The liquid's normals (after view_position.glsl): a plane fitted to the smoothed depth of the
// 7x7 pixels around each pixel (weighted least squares, Gaussian in distance), leaving out pixels
// with no liquid or more than the narrow range away in depth (another surface). A fit in two
// dimensions at once: one-sided differences turned small differences from one row to the next
// into streaks along the rows; the fit averages across rows as much as along them.
uniform sampler2D u_depth;
uniform ivec2 u_size;
uniform mat4 u_projection;
uniform float u_range;  // view units: farther in depth is another surface
layout(location = 0) out vec4 o_normal;
vec3 at(vec2 q, float d) { return view_position((q + 0.5) / vec2(u_size), d, u_projection); }
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  float d = texelFetch(u_depth, p, 0).r;
  if (d <= 0.0) {
    o_normal = vec4(0.0);
    return;
  }
  float w0 = 0.0, sx = 0.0, sy = 0.0, sz = 0.0, sxx = 0.0, syy = 0.0, sxy = 0.0, sxz = 0.0, syz = 0.0;
  for (int j = -3; j <= 3; ++j) {
    for (int i = -3; i <= 3; ++i) {
      ivec2 q = p + ivec2(i, j);
      if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, u_size))) continue;
      float z = texelFetch(u_depth, q, 0).r;
      if (z <= 0.0 || abs(z - d) > u_range) continue;
      float w = exp(-0.125 * float(i * i + j * j));
      float x = float(i), y = float(j);
      z -= d;
      w0 += w;
      sx += w * x;
      sy += w * y;
      sz += w * z;
      sxx += w * x * x;
      syy += w * y * y;
      sxy += w * x * y;
      sxz += w * x * z;
      syz += w * y * z;
    }
  }
  // Centred sums; then depth = d + a * dx + b * dy around the pixel.
  float cxx = sxx - sx * sx / w0, cyy = syy - sy * sy / w0, cxy = sxy - sx * sy / w0;
  float cxz = sxz - sx * sz / w0, cyz = syz - sy * sz / w0;
  float det = cxx * cyy - cxy * cxy;
  float a = 0.0, b = 0.0;
  if (det > 1e-6) {
    a = (cxz * cyy - cyz * cxy) / det;
    b = (cyz * cxx - cxz * cxy) / det;
  } else if (cxx > 1e-6) {
    a = cxz / cxx;
  } else if (cyy > 1e-6) {
    b = cyz / cyy;
  }
  vec2 q = vec2(p);
  vec3 c = at(q, d);
  vec3 n = normalize(cross(at(q + vec2(1.0, 0.0), d + a) - c, at(q + vec2(0.0, 1.0), d + b) - c));
  o_normal = vec4(n, 1.0);
}
