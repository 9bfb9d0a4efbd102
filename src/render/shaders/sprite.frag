// A sprite's pixels: its soft round coverage (or a texture), lit as a sphere under the sprite,
// shadowed by the light buffer where the look has self-shadowing (src/render/shaders/README.md).
in vec2 v_local;
flat in float v_half;
flat in vec2 v_axis;
in vec4 v_color;
in vec2 v_light_uv;
uniform int u_mode;          // 0 alpha (premultiplied), 1 additive, 2 alpha-tested
uniform int u_pass;          // 0: the eye, 1: the light buffer
uniform bool u_points;
uniform bool u_textured;
uniform sampler2D u_sprite;
uniform sampler2D u_light_buffer;
uniform bool u_shadows;
uniform bool u_shadow_blur;
uniform float u_light_texel;
uniform float u_shadow_density;
uniform bool u_lit;
uniform vec3 u_key;          // view space, towards the key light
uniform vec3 u_fill;         // view space, towards the fill light
out vec4 o_color;

// How much of the key light reaches here: 1 - the opacity the slices before laid down.
float transmittance(vec2 uv) {
  if (!u_shadows || any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1.0;
  float o = texture(u_light_buffer, uv).r;
  if (u_shadow_blur) {
    float t = 1.5 * u_light_texel;
    o = (2.0 * o + texture(u_light_buffer, uv + vec2(t, 0.0)).r + texture(u_light_buffer, uv - vec2(t, 0.0)).r +
         texture(u_light_buffer, uv + vec2(0.0, t)).r + texture(u_light_buffer, uv - vec2(0.0, t)).r) / 6.0;
  }
  return 1.0 - clamp(o, 0.0, 1.0);
}

void main() {
  vec2 c = u_points ? gl_PointCoord * 2.0 - 1.0 : v_local;
  c.x = sign(c.x) * max(abs(c.x) - v_half, 0.0);  // the streak's straight part is the disc's middle
  float r2 = dot(c, c);
  if (r2 > 1.0) discard;
  vec4 base = v_color;
  float coverage = 1.0 - smoothstep(0.55, 1.0, sqrt(r2));  // a soft round sprite
  if (u_textured) {  // the image upright: its first row (the top of the file) at the sprite's top
    base *= texture(u_sprite, vec2(c.x, u_points ? c.y : -c.y) * 0.5 + 0.5);
    coverage = 1.0;
  }
  float a = base.a * coverage;
  if (u_pass == 1) {
    float o = clamp(a * u_shadow_density, 0.0, 1.0);
    o_color = vec4(o, 0.0, 0.0, o);
    return;
  }
  float light = 1.0;
  if (u_lit) {  // a sphere under the sprite: key (shadowed), fill and rim lights over an ambient
    vec2 xy = u_points ? vec2(c.x, -c.y) : v_axis * c.x + vec2(-v_axis.y, v_axis.x) * c.y;
    vec3 n = vec3(xy, sqrt(1.0 - r2));
    float t = transmittance(v_light_uv);
    // Wrapped diffuse: a particle of a volume scatters some light past its terminator.
    float key = clamp(dot(n, u_key) * 0.6 + 0.4, 0.0, 1.0);
    float fill = max(dot(n, u_fill), 0.0);
    float rim = pow(1.0 - n.z, 3.0);
    light = 0.16 + 0.84 * key * t + 0.12 * fill + 0.2 * rim * t;
  }
  if (u_mode == 2) {
    if (base.a < 0.5) discard;
    o_color = vec4(base.rgb * light, 1.0);
    return;
  }
  // Additive light covers nothing: it adds, with no alpha to hide what is behind.
  o_color = vec4(base.rgb * light * a, u_mode == 1 ? 0.0 : a);
}
