// The particle codec's matching for clips without ids (src/format/particle_matching.hpp), on its
// own: generated frames whose true pairs are known, each frame's particles shuffled as a solver
// without ids may write them. The codec's tests (codec_test.cpp, playback_test.cpp) check what the
// pairs give a cooked clip: its size, its bounds and its interpolation.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <random>
#include <set>
#include <vector>

#include "format/particle_matching.hpp"

namespace {

using pstream::format::particle::GridPoints;
using pstream::format::particle::GridVelocity;
using pstream::format::particle::PositionMatcher;

// A frame's grid coordinates, an array an axis.
struct Frame {
  std::vector<std::uint32_t> q[3];
  std::uint32_t size() const { return static_cast<std::uint32_t>(q[0].size()); }
  void add(std::int64_t x, std::int64_t y, std::int64_t z) {
    q[0].push_back(static_cast<std::uint32_t>(static_cast<std::int32_t>(x)));
    q[1].push_back(static_cast<std::uint32_t>(static_cast<std::int32_t>(y)));
    q[2].push_back(static_cast<std::uint32_t>(static_cast<std::int32_t>(z)));
  }
  std::int64_t at(int a, std::uint32_t i) const { return static_cast<std::int32_t>(q[a][i]); }
  GridPoints points() const { return GridPoints{{q[0].data(), q[1].data(), q[2].data()}, size()}; }
};

// A lattice of side^3 particles `spacing` apart, from `origin` (negative coordinates included).
Frame lattice(int side, std::int64_t spacing, std::int64_t origin) {
  Frame f;
  for (int x = 0; x < side; ++x)
    for (int y = 0; y < side; ++y)
      for (int z = 0; z < side; ++z) f.add(origin + x * spacing, origin + y * spacing, origin + z * spacing);
  return f;
}

// The next frame: each previous particle i moved by move(i, a) and written at a shuffled place;
// truth[j] is the previous index of current particle j.
template <class Move>
Frame next_frame(const Frame& previous, std::mt19937& rng, const Move& move, std::vector<std::int64_t>& truth) {
  std::vector<std::uint32_t> order(previous.size());
  std::iota(order.begin(), order.end(), 0u);
  std::shuffle(order.begin(), order.end(), rng);
  Frame f;
  truth.clear();
  for (const std::uint32_t i : order) {
    f.add(previous.at(0, i) + move(i, 0), previous.at(1, i) + move(i, 1), previous.at(2, i) + move(i, 2));
    truth.push_back(i);
  }
  return f;
}

std::vector<std::int64_t> match(PositionMatcher& matcher, const Frame& previous, const Frame& current,
                                const GridVelocity& velocity = {}) {
  std::vector<std::int64_t> pairs(current.size(), -1);
  matcher.match(previous.points(), velocity, current.points(), pairs);
  return pairs;
}

// Every previous index at most once, and in range.
void expect_one_to_one(const std::vector<std::int64_t>& pairs, std::uint32_t previous_count) {
  std::set<std::int64_t> used;
  for (const std::int64_t i : pairs) {
    if (i < 0) continue;
    EXPECT_LT(i, std::int64_t(previous_count));
    EXPECT_TRUE(used.insert(i).second) << "previous particle " << i << " paired twice";
  }
}

std::size_t agreeing(const std::vector<std::int64_t>& pairs, const std::vector<std::int64_t>& truth) {
  std::size_t same = 0;
  for (std::size_t j = 0; j < pairs.size(); ++j) same += pairs[j] == truth[j] ? 1 : 0;
  return same;
}

// Matches `current` against `previous` with a fresh matcher and checks the pairs: one to one, and
// each the true one. Returns them.
std::vector<std::int64_t> expect_true_pairs(const Frame& previous, const Frame& current,
                                            const std::vector<std::int64_t>& truth) {
  PositionMatcher matcher;
  std::vector<std::int64_t> pairs = match(matcher, previous, current);
  expect_one_to_one(pairs, previous.size());
  EXPECT_EQ(agreeing(pairs, truth), std::size_t(current.size()));
  return pairs;
}

// Particles that move less than a third of their spacing are each paired with themselves, whatever
// order the frame lists them in, on both sides of the grid's zero.
TEST(Matching, ShuffledParticlesThatMoveLessThanTheirSpacingArePairedWithThemselves) {
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> jitter(-6, 6);
  const Frame previous = lattice(14, 40, -270);  // 2,744 particles, 40 grid steps apart
  std::vector<std::int64_t> truth;
  const Frame current = next_frame(
      previous, rng, [&](std::uint32_t, int) { return jitter(rng); }, truth);
  expect_true_pairs(previous, current, truth);
}

// A particle at exactly a previous particle's place (an inflow that re-seeds where it seeded) is
// paired with it, and its neighbours that moved most of the way towards it with their own.
TEST(Matching, ParticlesThatStayPutArePairedInPlace) {
  std::mt19937 rng(12);
  const Frame previous = lattice(10, 30, 1000);
  std::vector<std::int64_t> truth;
  // Every other particle along z stays; the others move 14 steps along z, 16 from the next one's
  // place.
  const Frame current = next_frame(
      previous, rng, [](std::uint32_t i, int a) { return i % 2 == 1 && a == 2 ? 14 : 0; }, truth);
  const std::vector<std::int64_t> pairs = expect_true_pairs(previous, current, truth);
  for (std::size_t j = 0; j < pairs.size(); ++j) {
    if (truth[j] % 2 == 0) {
      EXPECT_EQ(pairs[j], truth[j]) << "a particle that stayed put, current " << j;
    }
  }
}

// Births far from every previous particle stay unpaired, and the particles that died leave their
// previous indices unused: a birth is never paired with a dead particle across the frame.
TEST(Matching, BirthsFarAwayStayNewAndDeathsLeaveTheirIndicesUnused) {
  std::mt19937 rng(13);
  std::uniform_int_distribution<int> jitter(-4, 4);
  const Frame previous = lattice(12, 32, 0);
  std::vector<std::int64_t> survivors;
  Frame moved = next_frame(
      previous, rng, [&](std::uint32_t, int) { return jitter(rng); }, survivors);
  // Every fifth listed particle dies; 200 births appear 4,000 steps away.
  Frame current;
  std::vector<std::int64_t> truth;
  for (std::uint32_t j = 0; j < moved.size(); ++j) {
    if (j % 5 == 0) continue;
    current.add(moved.at(0, j), moved.at(1, j), moved.at(2, j));
    truth.push_back(survivors[j]);
  }
  for (int b = 0; b < 200; ++b) {
    current.add(4000 + 30 * (b % 10), 4000 + 30 * (b / 10 % 10), 4000 + 30 * (b / 100));
    truth.push_back(-1);
  }
  const std::vector<std::int64_t> pairs = expect_true_pairs(previous, current, truth);
  EXPECT_EQ(std::count(pairs.begin(), pairs.end(), -1), 200);
}

// Particles that persist and move further than their spacing (sparks exported without ids) are
// found again from where their stored velocity takes them; from where they were, the nearest
// particle is mostly another one.
TEST(Matching, ParticlesThatMoveFurtherThanTheirSpacingAreFoundAlongTheirVelocity) {
  std::mt19937 rng(14);
  const Frame previous = lattice(13, 20, -100);  // 2,197 particles
  // Each particle's velocity over a frame: 25 to 60 grid steps, in any direction; stored on a grid
  // of step 0.5 (units a second) at 24 frames a second, with a position step of 1/48, so that a
  // stored value v moves a particle v grid steps.
  std::uniform_int_distribution<int> speed(25, 60), sign(0, 1), jitter(-1, 1);
  Frame velocity;
  for (std::uint32_t i = 0; i < previous.size(); ++i) {
    std::int64_t v[3];
    for (std::int64_t& c : v) c = (sign(rng) != 0 ? 1 : -1) * speed(rng);
    velocity.add(v[0], v[1], v[2]);
  }
  GridVelocity stored;
  for (int a = 0; a < 3; ++a) {
    stored.q[std::size_t(a)] = velocity.q[a].data();
    stored.step[std::size_t(a)] = 0.5f;
    stored.origin[std::size_t(a)] = 0.0f;
    stored.position_step[std::size_t(a)] = 1.0 / 48.0;
  }
  stored.frame_seconds = 1.0 / 24.0;
  std::vector<std::int64_t> truth;
  const Frame current = next_frame(
      previous, rng, [&](std::uint32_t i, int a) { return velocity.at(a, i) + jitter(rng); }, truth);
  PositionMatcher matcher;
  const std::vector<std::int64_t> along = match(matcher, previous, current, stored);
  expect_one_to_one(along, previous.size());
  const std::vector<std::int64_t> plain = match(matcher, previous, current);
  expect_one_to_one(plain, previous.size());
  EXPECT_GE(agreeing(along, truth), current.size() * 99 / 100);
  EXPECT_LT(agreeing(plain, truth), current.size() / 2);
}

// A sparse frame on a fine grid (a few particles far apart, near both ends of the grid's range)
// takes the search through coarser cells than a dense one's: each particle is still paired with
// itself.
TEST(Matching, ASparseFrameAcrossTheWholeGridIsPairedToo) {
  std::mt19937 rng(16);
  std::uniform_int_distribution<std::int64_t> place(-16'000'000, 16'000'000);
  std::uniform_int_distribution<int> jitter(-50, 50);
  Frame previous;
  for (int i = 0; i < 400; ++i) previous.add(place(rng), place(rng), place(rng));
  previous.add(16'777'000, -16'777'000, 16'777'000);  // beside the grid's limit, 2^24 - 1
  std::vector<std::int64_t> truth;
  const Frame current = next_frame(
      previous, rng, [&](std::uint32_t, int) { return jitter(rng); }, truth);
  expect_true_pairs(previous, current, truth);
}

// Particles that all share one place (a solver's bad frame, or an emitter's first) pair with one
// another, one to one, and every one of them finds a partner.
TEST(Matching, ParticlesThatShareOnePlaceArePairedOneToOne) {
  Frame previous, current;
  for (int i = 0; i < 3000; ++i) previous.add(-5, 7, 11);
  for (int i = 0; i < 2500; ++i) current.add(-5, 7, 11);
  current.add(-5, 7, 12);
  PositionMatcher matcher;
  const std::vector<std::int64_t> pairs = match(matcher, previous, current);
  expect_one_to_one(pairs, previous.size());
  EXPECT_EQ(std::count(pairs.begin(), pairs.end(), -1), 0);
}

// Such a crowd that moves as one (particles parked at an emitter that moves): none of the current
// ones is at a previous one's place, so each is found by a search, and all of them are paired.
TEST(Matching, ACrowdThatMovesTogetherIsPairedOneToOne) {
  Frame previous, current;
  for (int i = 0; i < 3000; ++i) previous.add(-5, 7, 11);
  for (int i = 0; i < 2500; ++i) current.add(-4, 6, 13);
  current.add(-4, 6, 12);
  PositionMatcher matcher;
  const std::vector<std::int64_t> pairs = match(matcher, previous, current);
  expect_one_to_one(pairs, previous.size());
  EXPECT_EQ(std::count(pairs.begin(), pairs.end(), -1), 0);
}

// The matcher keeps its memory from frame to frame: a frame matched after larger and smaller ones
// pairs as it does with a fresh matcher, and empty frames pair nothing.
TEST(Matching, AReusedMatcherPairsAsAFreshOne) {
  std::mt19937 rng(15);
  std::uniform_int_distribution<int> jitter(-8, 8);
  const auto move = [&](std::uint32_t, int) { return jitter(rng); };
  std::vector<std::int64_t> truth;
  const Frame small = lattice(6, 25, 0), large = lattice(20, 25, -200);
  const Frame small_next = next_frame(small, rng, move, truth), large_next = next_frame(large, rng, move, truth);
  PositionMatcher fresh, reused;
  const std::vector<std::int64_t> expected = match(fresh, small, small_next);
  (void)match(reused, large, large_next);
  EXPECT_EQ(match(reused, small, small_next), expected);
  const Frame empty;
  EXPECT_EQ(match(reused, empty, small_next), std::vector<std::int64_t>(small_next.size(), -1));
  EXPECT_TRUE(match(reused, small, empty).empty());
  EXPECT_EQ(match(reused, small, small_next), expected);
}

}  // namespace
