// The liquid's surface over the scene (after view_position.glsl and sky.glsl): it reflects the
// sky, refracts and absorbs what is behind, adds the key light's highlight and writes the
// surface's depth.
uniform sampler2D u_depth;
uniform sampler2D u_normal;
uniform sampler2D u_thickness;
uniform sampler2D u_scene;
uniform vec2 u_viewport;
uniform vec2 u_liquid_size;
uniform mat4 u_projection;
uniform mat4 u_view;
uniform vec3 u_light;       // view space, towards the key light
uniform vec3 u_color;
uniform vec3 u_absorb;      // per view unit of thickness
uniform float u_color_depth;
uniform float u_refraction;
uniform float u_opacity_depth;  // view units of thickness that hide 63 % of what is behind; 0: clear
uniform int u_output;       // 0 shaded, 1 depth, 2 normals, 3 thickness
uniform float u_radius_at_1;  // a particle's radius in liquid pixels at distance 1
layout(location = 0) out vec4 o_color;
void main() {
  vec2 uv = gl_FragCoord.xy / u_viewport;
  ivec2 q = min(ivec2(uv * u_liquid_size), ivec2(u_liquid_size) - 1);
  float d = texelFetch(u_depth, q, 0).r;
  if (d <= 0.0) discard;
  vec3 p = view_position(uv, d, u_projection);
  vec4 clip = u_projection * vec4(p, 1.0);
  gl_FragDepth = clip.z / clip.w * 0.5 + 0.5;
  vec3 n = texelFetch(u_normal, q, 0).xyz;
  float thickness = texelFetch(u_thickness, q, 0).r;
  if (u_output == 1) {
    float near = u_projection[3][2] / (u_projection[2][2] - 1.0), far = u_projection[3][2] / (u_projection[2][2] + 1.0);
    o_color = vec4(vec3(1.0 - clamp((d - near) / (far - near), 0.0, 1.0)), 1.0);
    return;
  }
  if (u_output == 2) {
    o_color = vec4(n * 0.5 + 0.5, 1.0);
    return;
  }
  if (u_output == 3) {
    o_color = vec4(vec3(1.0 - exp(-thickness / u_color_depth)), 1.0);
    return;
  }
  vec3 v = normalize(-p);
  float fresnel = 0.02 + 0.98 * pow(1.0 - max(dot(n, v), 0.0), 5.0);
  vec3 reflected = sky_color(normalize(transpose(mat3(u_view)) * reflect(-v, n)));
  vec3 transmitted = exp(-u_absorb * thickness);
  vec2 bend = n.xy * u_refraction * 0.04 * (1.0 - exp(-thickness / u_color_depth));
  // A body of water scatters what crosses it: the scene behind is seen blurred, more so through
  // more liquid (up to 6 px, on a ring of 8 taps), and then hidden by the body's own light by
  // 1 - exp(-thickness / opacity_depth). A sheet a few particles thick reads as water, not glass.
  float opacity = u_opacity_depth > 0.0 ? 1.0 - exp(-thickness / u_opacity_depth) : 0.0;
  vec2 at = clamp(uv - bend, vec2(0.0), vec2(1.0));
  vec3 behind = texture(u_scene, at).rgb;
  if (opacity > 0.0) {
    float spread = 6.0 * opacity / u_viewport.y;
    for (int k = 0; k < 8; ++k) {
      float a = 0.785398 * float(k);
      behind += texture(u_scene, clamp(at + spread * vec2(cos(a) * u_viewport.y / u_viewport.x, sin(a)), vec2(0.0), vec2(1.0))).rgb;
    }
    behind /= 9.0;
  }
  vec3 scattered = 0.5 * u_color * (1.0 - transmitted);  // light the liquid scatters back, tinted
  // The body's own light: the liquid's colour, lit from the key light, darker and more saturated
  // the deeper it is (the light it scatters back crossed some of it).
  vec3 body = u_color * sqrt(transmitted) * (0.45 + 0.55 * max(dot(n, u_light), 0.0));
  vec3 under = mix(behind * transmitted + scattered, body, opacity);
  // The key light's highlight, its sharpness from how much the normals vary around the pixel
  // (Toksvig 2005): the mean of the unit normals over 3x3 taps a particle's radius apart (2 to 8
  // pixels, so the same part of the surface at any image size) is shorter where they disagree,
  // and a sharp highlight there would alias into glints that the foreshortening of a surface seen
  // at a grazing angle draws out into bright lines along the rows. Flat water keeps the sharp one.
  vec3 mean_n = vec3(0.0);
  float taps = 0.0;
  int spacing = clamp(int(round(u_radius_at_1 / d)), 2, 8);
  for (int j = -1; j <= 1; ++j) {
    for (int i = -1; i <= 1; ++i) {
      ivec2 t = clamp(q + ivec2(i, j) * spacing, ivec2(0), ivec2(u_liquid_size) - 1);
      if (texelFetch(u_depth, t, 0).r <= 0.0) continue;
      mean_n += texelFetch(u_normal, t, 0).xyz;
      taps += 1.0;
    }
  }
  float agree = clamp(length(mean_n) / max(taps, 1.0), 0.0, 1.0);
  const float kShininess = 180.0;
  float shininess = kShininess * agree / (agree + kShininess * (1.0 - agree));
  vec3 h = normalize(u_light + v);
  // Scaled by (1 + shininess) / (1 + kShininess): a broader highlight spreads the same light.
  float highlight = dot(n, u_light) > 0.0
      ? 1.6 * (1.0 + shininess) / (1.0 + kShininess) * pow(max(dot(n, h), 0.0), shininess) : 0.0;
  o_color = vec4(mix(under, reflected, fresnel) + vec3(highlight), 1.0);
}
