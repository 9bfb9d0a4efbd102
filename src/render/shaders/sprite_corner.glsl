// A sprite's corner in view space (docs/rendering.md, "Sprites"). The including vertex shader
// declares `vec4 view` (the particle's centre in view space), the radius and colour, and calls
// sprite_corner() last; it writes the varyings below.
uniform mat4 u_projection;
uniform mat4 u_light_projection;
uniform float u_viewport_height;
uniform float u_shutter;     // seconds of motion a sprite is stretched over
uniform float u_min_pixels;
out vec2 v_local;            // in radii: along the streak, across it
flat out float v_half;       // half the streak's straight part, in radii
flat out vec2 v_axis;        // the streak's direction on screen

// The radius in pixels of a sphere of `radius` at view-space depth `view_z`.
float sprite_pixels(float radius, float view_z) {
  return radius * u_projection[1][1] * u_viewport_height * 0.5 / max(-view_z, 1e-6);
}

// Below u_min_pixels of radius a sprite is drawn at that size, fainter by the area it lost.
void floor_size(float pixels, inout float radius, inout float alpha) {
  if (pixels < u_min_pixels && pixels > 0.0) {
    float k = pixels / u_min_pixels;
    alpha *= k * k;
    radius /= k;
  }
}

// Corner `corner` ((-1,-1) (1,-1) (-1,1) (1,1)) of the sprite at `view`: a disc of `radius`, or,
// with a shutter, the disc swept along the screen-space motion of `velocity` (view space, units
// per second) over u_shutter seconds, as bright in total as the disc (its alpha shrinks by the
// area it gained). Returns the corner's clip-space position.
vec4 sprite_corner(vec4 view, vec3 velocity, float radius, vec2 corner, inout float alpha) {
  v_half = 0.0;
  v_axis = vec2(1.0, 0.0);
  if (u_shutter > 0.0) {
    vec2 d = velocity.xy * u_shutter;
    float len = length(d);
    if (len > 1e-4 * radius) {
      v_axis = d / len;
      v_half = 0.5 * len / radius;
      // The soft disc's coverage integrates to 1.9187 (in radii squared); each radius of straight
      // part adds 2 x 0.775 (its cross-section's integral).
      alpha *= 1.0 / (1.0 + 1.6157 * v_half);
    }
  }
  v_local = vec2(corner.x * (1.0 + v_half), corner.y);
  view.xy += (v_axis * v_local.x + vec2(-v_axis.y, v_axis.x) * v_local.y) * radius;
  return u_projection * view;
}

// Corner `corner` of the sprite at `light_view` (its centre in the light's view) in the light
// buffer: a disc of `radius` facing the light. Returns the corner's position in the light's clip space.
vec4 light_corner(vec4 light_view, float radius, vec2 corner) {
  v_half = 0.0;
  v_axis = vec2(1.0, 0.0);
  v_local = corner;
  light_view.xy += corner * radius;
  return u_light_projection * light_view;
}
