// A look's shadow on the ground (after ground_ray.glsl): where this pixel's ray meets the ground,
// the light buffer's opacity (a 3x3 blur of it) times u_strength darkens the ground, drawn
// multiplied over it (blending ZERO, SRC_COLOR).
uniform float u_ground_height;
uniform mat4 u_light_view;        // world -> the light's view
uniform mat4 u_light_projection;  // -> its clip space
uniform sampler2D u_light_buffer;
uniform float u_light_texel;
uniform float u_strength;  // how dark the ground gets under a fully opaque column, 0..1
out vec4 o_color;
void main() {
  vec3 dir, hit;
  float t;
  if (!ground_ray(u_ground_height, dir, t, hit)) discard;
  vec4 l = u_light_projection * (u_light_view * vec4(hit, 1.0));
  vec2 uv = l.xy * 0.5 + 0.5;
  if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) discard;
  float o = 0.0;
  for (int y = -1; y <= 1; ++y)
    for (int x = -1; x <= 1; ++x) o += texture(u_light_buffer, uv + 2.0 * u_light_texel * vec2(x, y)).r;
  o_color = vec4(vec3(1.0 - u_strength * clamp(o / 9.0, 0.0, 1.0)), 1.0);
}
