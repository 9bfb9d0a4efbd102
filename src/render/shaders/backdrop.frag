// The sky gradient and the ground grid (after sky.glsl and ground_ray.glsl): each pixel's view
// ray either meets the ground plane (grid lines fading into the horizon's haze; depth written)
// or shows the sky.
uniform bool u_ground;
uniform float u_ground_height;
uniform float u_grid;
out vec4 o_color;
void main() {
  vec3 dir, hit;
  float t;
  bool on_ground = ground_ray(u_ground_height, dir, t, hit);
  vec3 sky = sky_color(dir);
  if (!u_ground || !on_ground) {
    o_color = vec4(sky, 1.0);
    gl_FragDepth = 1.0;
    return;
  }
  vec2 g = hit.xz / u_grid;
  vec2 w = fwidth(g);
  vec2 line = abs(fract(g - 0.5) - 0.5) / max(w, vec2(1e-6));
  float on_line = 1.0 - min(min(line.x, line.y), 1.0);
  on_line *= 1.0 - smoothstep(0.15, 0.6, max(w.x, w.y));  // lines closer than a few pixels fade out
  vec3 ground = mix(vec3(0.30, 0.31, 0.33), vec3(0.48, 0.50, 0.53), on_line);
  float haze = 1.0 - exp(-t / (60.0 * u_grid));
  o_color = vec4(mix(ground, sky_color(vec3(dir.x, 0.0, dir.z)), haze), 1.0);
  vec4 clip = u_projection * u_view * vec4(hit, 1.0);
  gl_FragDepth = clamp(clip.z / clip.w * 0.5 + 0.5, 0.0, 1.0);
}
