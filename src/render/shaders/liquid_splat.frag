// A liquid splat's fragment (after liquid_splat.glsl's vertex stage): pass 0 writes the sphere's
// front depth (distance along the view axis, with its coverage) and depth-tests it; 1 adds its
// chord length to the thickness; 2 draws spray; 3, seen along the light, its opacity to the light
// buffer: 1 - exp(-chord / u_shadow_depth), which the buffer's "over" blending multiplies into
// exp(-(the chords' sum) / u_shadow_depth) of light let through.
in vec2 v_corner;
in vec3 v_center;
in float v_radius;
in float v_foam;
uniform mat4 u_projection;
uniform int u_pass;
uniform float u_shadow_depth;  // pass 3: view units
layout(location = 0) out vec4 o_out;
void main() {
  float r2 = dot(v_corner, v_corner);
  if (r2 > 1.0) discard;
  float h = sqrt(1.0 - r2);
  if (u_pass == 0) {
    vec3 p = v_center + vec3(v_corner * v_radius, h * v_radius);
    vec4 c = u_projection * vec4(p, 1.0);
    gl_FragDepth = c.z / c.w * 0.5 + 0.5;
    o_out = vec4(-p.z, 1.0, 0.0, 0.0);  // depth x coverage, coverage (the filter reads both)
    return;
  }
  gl_FragDepth = gl_FragCoord.z;
  if (u_pass == 1) {
    o_out = vec4(2.0 * h * v_radius, 0.0, 0.0, 0.0);
    return;
  }
  if (u_pass == 3) {
    o_out = vec4(1.0 - exp(-2.0 * h * v_radius / u_shadow_depth));
    return;
  }
  float a = v_foam * 0.85 * (1.0 - smoothstep(0.2, 1.0, sqrt(r2)));
  o_out = vec4(vec3(0.93, 0.96, 1.0) * a, a);
}
