// A pixel's view-space position from its uv and its depth (distance along the view axis).
vec3 view_position(vec2 uv, float d, mat4 projection) {
  vec2 ndc = uv * 2.0 - 1.0;
  return vec3(ndc.x * d / projection[0][0], ndc.y * d / projection[1][1], -d);
}
