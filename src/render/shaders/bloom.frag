// One axis of the bloom's Gaussian, into a half-resolution buffer: read through bilinear
// filtering, a tap between texels averages them, so the first pass also halves the full-size
// buffer. The weights sum to one: the blur keeps the light's total.
uniform sampler2D u_source;
uniform vec2 u_step;        // one destination texel along the axis, in the source's uv
uniform float u_sigma;      // in destination texels
uniform int u_taps;         // each side
uniform vec2 u_size;        // the destination's size
out vec4 o_color;
void main() {
  vec2 uv = gl_FragCoord.xy / u_size;
  vec4 sum = texture(u_source, uv);
  float weights = 1.0;
  for (int i = 1; i <= u_taps; ++i) {
    float w = exp(-0.5 * float(i * i) / (u_sigma * u_sigma));
    sum += w * (texture(u_source, uv + float(i) * u_step) + texture(u_source, uv - float(i) * u_step));
    weights += 2.0 * w;
  }
  o_color = sum / weights;
}
