// The sky's colour along a unit world direction (y up): the backdrop draws it, the liquid
// reflects it.
vec3 sky_color(vec3 d) {
  const vec3 zenith = vec3(0.13, 0.27, 0.52), horizon = vec3(0.58, 0.66, 0.75), below = vec3(0.16, 0.17, 0.19);
  if (d.y >= 0.0) return mix(horizon, zenith, pow(d.y, 0.55));
  return mix(horizon, below, pow(-d.y, 0.35));
}
