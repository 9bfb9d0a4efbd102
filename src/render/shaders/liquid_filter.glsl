// The liquid's depth filter, in two dimensions at once (docs/rendering.md, "Liquid"): the including
// shader defines `const int kPairs` first and stores liquid_filter(p) for each pixel p (natively a
// compute pass, in the browser a fragment pass). The radius in pixels is a world length projected
// at the centre pixel's depth. Depth 0 is "no liquid" and stays so: silhouettes do not move.
//
// Why two dimensions: a separable filter treats each line on its own. Where the narrow range
// leaves samples out (a silhouette, a drop in front of the pool), one line takes samples that the
// next leaves out, and the lines differ: at 1080p, lines and crosses a filter radius long at every
// edge and behind every drop.
//
// Its cost does not grow with the radius: kPairs pairs of taps on a sunflower spiral over the disc
// (Vogel's: each tap stands for the same area, and no two rows line up, so the taps alias into
// faint noise, not into a lattice as a square grid of sparse taps did). Every buffer it reads holds
// (depth x coverage, coverage), coverage 1 where there is liquid, and taps read it bilinearly: a
// tap's position and what it reads change continuously with the radius, so that neighbouring
// pixels at slightly different depths do not take different sets of pixels.
uniform sampler2D u_depth;    // depth x coverage, coverage
uniform ivec2 u_size;
uniform float u_radius_at_1;  // filter radius in pixels at distance 1
uniform float u_range;        // the narrow range, view units
uniform int u_mode;           // 0 narrow range, 1 bilateral, 2 gaussian
uniform float u_scale;        // this pass's radius, a fraction of the filter's
const float kMaxRadius = 48.0;
// The spiral's taps for this pass (turned from the last pass's): each one's offset at radius 1
// (one of a pair; the other is its negative) and its Gaussian weight (sigma half the radius).
uniform vec3 u_taps[kPairs];
// The depth at p + o and how much of the tap has liquid (0..1).
vec2 tap(ivec2 p, vec2 o) {
  vec2 v = textureLod(u_depth, (vec2(p) + 0.5 + o) / vec2(u_size), 0.0).rg;
  return vec2(v.y > 1e-4 ? v.x / v.y : 0.0, v.y);
}
vec2 liquid_filter(ivec2 p) {
  float z0 = texelFetch(u_depth, p, 0).r;
  float radius = u_scale * min(u_radius_at_1 / max(z0, 1e-6), kMaxRadius);
  if (z0 <= 0.0 || radius < 0.5) {
    return vec2(z0, z0 > 0.0 ? 1.0 : 0.0);
  }
  float sum = 0.0, weights = 0.0;
  float half_range = 0.5 * u_range;
  for (int i = 0; i < kPairs; ++i) {
    vec2 o = radius * u_taps[i].xy;
    vec2 a = tap(p, o), b = tap(p, -o);
    float g = u_taps[i].z;
    if (u_mode == 0) {
      // The narrow range (after Truong and Yuksel 2018) as point-symmetric pairs: the taps at
      // +o and -o count together, so that the kernel stays symmetric and a pixel beside an edge
      // is not pulled towards either side. A pair counts as much as both have liquid, and as
      // much as their mean lies within half the range of the centre: on a plane, however steep
      // (water seen at a grazing angle), the mean of a symmetric pair is the centre's depth,
      // while a pair with one tap on another layer (a drop in front, the floor behind a sheet) is
      // off by half the gap. The weight falls as (1 - off / half range)^2, so that no pair
      // switches on or off from one pixel to the next.
      float off = abs(0.5 * (a.x + b.x) - z0);
      float fade = max(1.0 - off / half_range, 0.0);
      float w = g * min(a.y, b.y) * fade * fade;
      sum += w * (a.x + b.x);
      weights += 2.0 * w;
    } else {
      float wa = g * a.y, wb = g * b.y;  // nothing there: the silhouette stays put
      if (u_mode == 1) {
        wa *= exp(-((a.x - z0) * (a.x - z0)) / (2.0 * u_range * u_range));
        wb *= exp(-((b.x - z0) * (b.x - z0)) / (2.0 * u_range * u_range));
      }
      sum += wa * a.x + wb * b.x;
      weights += wa + wb;
    }
  }
  // The centre stands for its own share of the disc, weighted as the innermost taps are.
  float w0 = exp(-0.5 / float(kPairs));
  return vec2((sum + w0 * z0) / (weights + w0), 1.0);
}
