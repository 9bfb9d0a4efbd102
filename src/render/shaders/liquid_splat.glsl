// A liquid splat's corner: one quad per particle, a sphere's front depth (pass 0), its thickness
// (1), spray (2: particles where the liquid is thin, isolated, or that move fast) or its opacity
// in the light buffer (3: `view` is then the light's view, u_projection its). The including
// vertex shader finds the particle's view-space centre, its radius and its speed (view units; the
// speed negative where the clip has no velocity) and returns liquid_splat_corner()'s position.
uniform mat4 u_projection;
uniform int u_pass;
uniform sampler2D u_thickness;
uniform float u_foam_speed;      // view units per second; 0: off
uniform float u_foam_thickness;  // view units; 0: off
out vec2 v_corner;
out vec3 v_center;
out float v_radius;
out float v_foam;
vec4 liquid_splat_corner(vec4 view, float r, float speed) {
  v_corner = vec2(float(gl_VertexID & 1) * 2.0 - 1.0, float(gl_VertexID >> 1) * 2.0 - 1.0);
  v_center = view.xyz;
  v_radius = r;
  v_foam = 0.0;
  if (u_pass == 2) {
    vec4 c = u_projection * view;
    vec2 uv = c.xy / c.w * 0.5 + 0.5;
    float foam = 0.0;
    if (u_foam_thickness > 0.0 && c.w > 0.0 && all(greaterThan(uv, vec2(0.0))) && all(lessThan(uv, vec2(1.0)))) {
      float t = texture(u_thickness, uv).r;
      foam = 1.0 - smoothstep(0.5 * u_foam_thickness, u_foam_thickness, t);
    }
    if (u_foam_speed > 0.0 && speed >= 0.0) foam = max(foam, smoothstep(u_foam_speed, 1.5 * u_foam_speed, speed));
    v_foam = foam;
    if (foam < 0.02) return vec4(2.0, 2.0, 2.0, 1.0);  // not spray: outside the clip volume
    view.z += r;  // on the surface of the liquid the particle is in, not inside it
    r *= 0.8;
  }
  view.xy += v_corner * r;
  return u_projection * view;
}
