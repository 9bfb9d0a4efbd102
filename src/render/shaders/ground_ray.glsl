// A full-screen pass's view ray through this pixel, and where it meets the ground plane y = h.
uniform mat4 u_view;
uniform mat4 u_projection;
uniform vec2 u_viewport;
bool ground_ray(float h, out vec3 dir, out float t, out vec3 hit) {
  vec2 ndc = gl_FragCoord.xy / u_viewport * 2.0 - 1.0;
  mat3 to_world = transpose(mat3(u_view));
  vec3 eye = -(to_world * u_view[3].xyz);
  dir = normalize(to_world * vec3(ndc.x / u_projection[0][0], ndc.y / u_projection[1][1], -1.0));
  t = (h - eye.y) / dir.y;
  hit = eye + t * dir;
  return dir.y < 0.0 && t > 0.0;
}
