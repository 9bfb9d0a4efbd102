// The accumulated sprites over the scene: bloom, exposure and tone map, premultiplied.
uniform sampler2D u_hdr;
uniform sampler2D u_bloom;   // the HDR light blurred at half resolution
uniform float u_bloom_strength;
uniform float u_exposure;
uniform int u_tone_map;      // 0 filmic, 1 linear
out vec4 o_color;
float filmic(float x) {      // a fitted ACES curve, on 1.4 x so that white comes out near 87 %
  x *= 1.4;
  return clamp(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}
void main() {
  vec4 h = texelFetch(u_hdr, ivec2(gl_FragCoord.xy), 0);
  // Bloom moves a share of the light into its blur: what glows spreads, and the light's total
  // stays what it was.
  if (u_bloom_strength > 0.0) h = mix(h, texture(u_bloom, gl_FragCoord.xy / vec2(textureSize(u_hdr, 0))), u_bloom_strength);
  vec3 c = max(h.rgb, vec3(0.0)) * u_exposure;
  if (u_tone_map == 0) {
    float m = max(max(c.r, c.g), c.b);
    c = m > 0.0 ? c * (filmic(m) / m) : vec3(0.0);
  } else {
    c = clamp(c, 0.0, 1.0);
  }
  o_color = vec4(c, clamp(h.a, 0.0, 1.0));
}
