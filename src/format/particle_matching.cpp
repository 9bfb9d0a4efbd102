// The particle codec's matching for a clip without ids (particle_matching.hpp): a frame's particles
// paired with the frame before's by position, closest first. The encoder's alone; its pairs reach
// the decoder as the packet's operations.
#include "format/particle_matching.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <numeric>
#include <span>
#include <tuple>

#include "format/particle_common.hpp"
#include "particlestream/sort.hpp"

namespace pstream::format::particle {
namespace {

// a / b rounded down (b > 0): the cell a grid coordinate falls in.
std::int64_t floordiv(std::int64_t a, std::int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
// A cell's key where the matching sorts cells: 21 bits of each cell coordinate (cells that share
// a key are told apart by the distance every candidate is checked against).
std::uint64_t cell_key(std::int64_t x, std::int64_t y, std::int64_t z) {
  return (std::uint64_t(x & 0x1fffff) << 42) | (std::uint64_t(y & 0x1fffff) << 21) | std::uint64_t(z & 0x1fffff);
}
// The squared distance between two grid positions (below 2^52: grid values are below 2^24).
std::int64_t squared_distance(const std::int64_t* a, const std::int64_t* b) {
  return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]);
}

// A particle's nearest candidates, at most N, sorted by key (distance, then current index): `key`
// goes in unless they are full and it is not below the last, which it then pushes out.
template <class Key, std::size_t N>
void keep_nearest(Key (&best)[N], int& found, const Key& key) {
  if (found == int(N) && !(key < best[N - 1])) return;
  int slot = found < int(N) ? found++ : int(N) - 1;
  for (; slot > 0 && key < best[slot - 1]; --slot) best[slot] = best[slot - 1];
  best[slot] = key;
}

// A candidate pair: squared distance, previous and current index.
struct Pair {
  std::int64_t distance;
  std::uint32_t prev, cur;
};
// Kept for each previous particle: 6 rather than 8 makes the FLIP pour 0.6 % larger and its
// encode about 1.13x as fast (docs/compression-experiments.md, "Six candidates a
// particle").
constexpr int kCandidates = 6;
// The most candidates one search reads (the FLIP pour's read 68 on average, 566 at most). A
// clump far denser than the frame's average (particles a grid step apart, beside a stray one far
// away that makes the cells large) would otherwise have each search read the whole clump: 8,000
// particles took 6.8 s to cook, 40,000 5 minutes. A search that stops keeps the nearest of
// what it read.
constexpr std::uint32_t kMostRead = 4096;
struct Offset {  // a cell offset, and the least squared distance across it
  std::int64_t bound;
  int d[3];
};
// A place of current particles left over by the pairing: its cell's key, its position and its
// first unpaired particle's index (kept beside the key: read through `at` instead, with a binary
// search for each cell in place of CellRanges, the pairing took 280-300 us a frame of the FLIP
// pour where it takes 225).
struct Spare {
  std::uint64_t key;
  std::int64_t q[3];
  std::uint32_t j;
  bool operator<(const Spare& o) const { return std::tie(key, j) < std::tie(o.key, o.j); }
};
// Where each cell's particles are in a list sorted by cell key: an open-addressed table from a
// key to the range of its particles (one probe or two where a binary search took ten steps).
struct CellRanges {
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};  // cell_key() is below 2^63
  std::vector<std::uint64_t> keys;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> ranges;
  std::uint64_t mask = 0;
  int shift = 64;
  void build(std::span<const Spare> sorted) {
    const std::size_t size = std::bit_ceil(std::max<std::size_t>(16, 2 * sorted.size()));
    keys.assign(size, kEmpty);
    ranges.resize(size);
    mask = size - 1;
    shift = 64 - std::countr_zero(size);
    for (std::size_t t = 0; t < sorted.size();) {
      std::size_t u = t + 1;
      while (u < sorted.size() && sorted[u].key == sorted[t].key) ++u;
      std::uint64_t h = slot(sorted[t].key);
      while (keys[h] != kEmpty) h = (h + 1) & mask;
      keys[h] = sorted[t].key;
      ranges[h] = {std::uint32_t(t), std::uint32_t(u)};
      t = u;
    }
  }
  std::pair<std::uint32_t, std::uint32_t> find(std::uint64_t key) const {
    for (std::uint64_t h = slot(key); keys[h] != kEmpty; h = (h + 1) & mask)
      if (keys[h] == key) return ranges[h];
    return {0, 0};
  }
  std::uint64_t slot(std::uint64_t key) const { return (key * 0x9E3779B97F4A7C15ull) >> shift; }
};
// This frame's particles by their exact quantised place, in an open-addressed table: at each place
// the particles there, lowest index first, handed out one at a time by take(). `at` holds each
// particle's place in its first 3 of every 6 numbers.
struct ExactPlaces {
  static constexpr std::uint32_t kNone = ~std::uint32_t{0};
  std::vector<std::uint32_t> slot;     // the lowest index at each place
  std::vector<std::uint32_t> untaken;  // per slot: the lowest index there not yet taken
  std::vector<std::uint32_t> next;     // per particle: the next index at its place
  std::uint64_t mask = 0;
  const std::int64_t* at = nullptr;
  void build(std::uint32_t n, const std::int64_t* places) {
    const std::size_t size = std::bit_ceil(std::max<std::size_t>(16, 2 * std::size_t(n)));
    slot.assign(size, kNone);
    next.resize(n);
    mask = size - 1;
    at = places;
    for (std::uint32_t j = n; j-- > 0;) {  // from the last, so that each place lists its lowest first
      std::uint32_t& s = slot[probe(&at[std::size_t(j) * 6])];
      next[j] = s;
      s = j;
    }
    untaken = slot;
  }
  // The lowest index at q's place not taken before, now taken; kNone when there is none left.
  std::uint32_t take(const std::int64_t* q) {
    const std::uint64_t h = probe(q);
    const std::uint32_t j = untaken[h];
    if (j != kNone) untaken[h] = next[j];
    return j;
  }
  // The lowest index at slot h's place that `match` leaves unpaired (kNone if none), once
  // restart() has set each place's cursor to its lowest index: a particle once paired stays
  // paired, so the cursor only moves on.
  void restart() { untaken = slot; }
  std::uint32_t first_unpaired(std::uint64_t h, const std::vector<std::int64_t>& match) {
    std::uint32_t& j = untaken[h];
    while (j != kNone && match[j] >= 0) j = next[j];
    return j;
  }
  // The slot that holds q's place, or the empty one where it would go.
  std::uint64_t probe(const std::int64_t* q) const {
    const std::uint64_t k = (std::uint64_t(std::uint32_t(q[0])) * 0x9E3779B97F4A7C15ull) ^
                            (std::uint64_t(std::uint32_t(q[1])) * 0xC2B2AE3D27D4EB4Full) ^
                            (std::uint64_t(std::uint32_t(q[2])) * 0x165667B19E3779F9ull);
    std::uint64_t h = (k ^ (k >> 29)) & mask;
    for (; slot[h] != kNone; h = (h + 1) & mask) {
      const std::int64_t* o = &at[std::size_t(slot[h]) * 6];
      if (o[0] == q[0] && o[1] == q[1] && o[2] == q[2]) break;
    }
    return h;
  }
};

}  // namespace

// The matcher's working memory, kept from frame to frame: made afresh, its larger arrays
// were pages the kernel mapped and cleared for every frame.
struct PositionMatcher::Scratch {
  std::vector<std::int64_t> at, sorted;
  std::vector<Pair> slots, saved, pairs;
  std::vector<std::uint8_t> kept, saved_kept, prev_taken;
  std::vector<std::int32_t> steps, e;
  std::vector<std::uint32_t> start, order, fill, visit_start, visit, all, rest, sample, by_distance;
  ExactPlaces places;  // this frame's particles by their exact place
  std::vector<float> xs, ys, zs;
  std::vector<Offset> offsets;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> sorted_cells;
  std::vector<std::size_t> cell_of_particle;
  std::vector<std::uint64_t> nearest_prev, items, scratch;
  std::vector<Spare> spare;             // Matching::pair_leftovers()'s places of current particles
  std::vector<std::uint32_t> left;      // and its previous ones
  CellRanges spare_cells;               // where `spare` holds each cell's
  std::vector<std::uint8_t> known;      // and what it knows of each previous particle's candidates
  std::vector<std::uint64_t> place_of;  // and each place's slot in `places`, by its first index
};

namespace {

// One frame's matching: the frames' particles, and the matcher's memory.
class Matching {
 public:
  Matching(PositionMatcher::Scratch& scratch, const GridPoints& previous, const GridVelocity& velocity,
           const GridPoints& current)
      : scratch_(scratch), previous_(previous), current_(current), velocity_(velocity) {}

  // Without ids: previous and current particles are paired closest first, within about one
  // particle spacing. Measured on the Mantaflow FLIP fixture, pairing plain positions beats
  // pairing positions moved on by the last step (2.29 against 2.41 bytes per particle) or
  // moved back along the velocity (3.04): a FLIP solver re-samples its particles every frame and
  // most move less than a spacing; the motion is left to the predictor. Particles that persist
  // and move further than a spacing are paired from where their stored velocity takes them, when
  // a sample finds them nearer that way (below). Otherwise the particles left over are paired
  // among themselves (pair_leftovers()).
  void run(std::vector<std::int64_t>& match) {
    const std::uint32_t n = current_.count;
    if (previous_.count == 0 || n == 0) return;
    std::int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) std::tie(lo[a], hi[a]) = signed_extremes(std::span(current_.q[std::size_t(a)], n));
    const double volume = double(hi[0] - lo[0] + 1) * double(hi[1] - lo[1] + 1) * double(hi[2] - lo[2] + 1);
    const std::int64_t cell = std::max<std::int64_t>(2, std::llround(std::cbrt(volume / n)));
    // Each current particle's position and cell (of side `cell`), six numbers together.
    Scratch& m = scratch_;
    std::vector<std::int64_t>& at = m.at;
    at.resize(std::size_t(n) * 6);
    for (std::uint32_t j = 0; j < n; ++j) {
      for (int a = 0; a < 3; ++a) {
        at[std::size_t(j) * 6 + a] = static_cast<std::int32_t>(current_.q[std::size_t(a)][j]);
        at[std::size_t(j) * 6 + 3 + a] = floordiv(at[std::size_t(j) * 6 + a], cell);
      }
    }
    // A particle's candidates are the current particles in the 3x3x3 cells (of side `cell`) around
    // it, within `reach`; of those, its kCandidates nearest (ties by index) are kept. The result
    // depends on nothing else, so the search may visit them in any order and stop early.
    // Each previous particle's kept candidates in its own slots, so that the searches may run in
    // any order and the pairs still come out in previous-index order.
    std::vector<Pair>& slots = m.slots;
    std::vector<std::uint8_t>& kept = m.kept;
    slots.resize(std::size_t(previous_.count) * kCandidates);
    kept.assign(previous_.count, 0);
    const std::int64_t reach = cell * cell * 2;  // squared: about 1.4 spacings
    // Where each previous particle is searched from: where it was, or moved on by its stored
    // velocity (below), 3 numbers a particle.
    const std::uint32_t* const was[3] = {previous_.q[0], previous_.q[1], previous_.q[2]};
    std::vector<std::int32_t>& steps = m.steps;  // 3 a previous particle: its velocity's step (below)
    const std::int32_t* moved = nullptr;         // steps.data() while searching from the moved places
    const auto from = [&](std::uint32_t i, int a) {
      const std::int64_t q = static_cast<std::int32_t>(was[a][i]);
      return moved == nullptr ? q : q + moved[std::size_t(i) * 3 + std::size_t(a)];
    };
    const auto search = [&](std::uint32_t i, const auto& visit_cells) {
      const std::int64_t p[3] = {from(i, 0), from(i, 1), from(i, 2)};
      const std::int64_t home[3] = {floordiv(p[0], cell), floordiv(p[1], cell), floordiv(p[2], cell)};
      std::pair<std::int64_t, std::uint32_t> best[kCandidates];  // (distance, current index)
      int found = 0;
      std::uint32_t read = 0;
      const auto consider = [&](std::uint32_t j, const std::int64_t* s) {  // s: position and cell
        ++read;
        const std::int64_t e = squared_distance(s, p);
        if (e > reach) return;
        for (int a = 0; a < 3; ++a) {
          if (s[3 + a] < home[a] - 1 || s[3 + a] > home[a] + 1) return;
        }
        keep_nearest(best, found, std::pair{e, j});
      };
      // The worst distance kept, once there are enough candidates: cells that cannot hold a
      // closer particle are not visited. -1 once kMostRead candidates are read: the search stops.
      const auto worst = [&] {
        return read >= kMostRead ? -1 : found == kCandidates ? best[kCandidates - 1].first : reach;
      };
      visit_cells(p, home, consider, worst);
      for (int b = 0; b < found; ++b)
        slots[std::size_t(i) * kCandidates + std::size_t(b)] = Pair{best[b].first, i, best[b].second};
      kept[i] = static_cast<std::uint8_t>(found);
    };
    // A dense grid over this frame's box only when it is not much larger than the frame.
    const double most_cells = 16.0 * n + 4096.0;
    // This frame's particles by cell, as the search below reads them: made by the first
    // searches() and kept for the next.
    std::vector<std::uint32_t>&start = m.start, &order = m.order;
    std::vector<float>&xs = m.xs, &ys = m.ys, &zs = m.zs;
    std::vector<std::int32_t>& e = m.e;
    std::vector<std::int64_t>& sorted = m.sorted;
    std::vector<Offset>& offsets = m.offsets;
    std::vector<std::pair<std::uint64_t, std::uint32_t>>& sorted_cells = m.sorted_cells;
    offsets.clear();
    bool prepared = false;
    // The searches of the previous particles `previous` (indices), into their slots.
    const auto searches = [&](std::span<const std::uint32_t> previous, bool in_cell_order) {
      const auto searched = static_cast<std::uint32_t>(previous.size());
      // Particles 0..count-1 by their cells (a counting sort, stable): `order` lists them, and cell
      // c's are order[start[c]] to order[start[c + 1] - 1]. Each particle's cell is found once.
      std::vector<std::size_t>& cell_of_particle = m.cell_of_particle;
      const auto by_cell = [&](std::size_t cells, std::uint32_t count, const auto& cell_of,
                               std::vector<std::uint32_t>& start, std::vector<std::uint32_t>& order) {
        start.assign(cells + 1, 0);
        cell_of_particle.resize(count);
        for (std::uint32_t j = 0; j < count; ++j) {
          cell_of_particle[j] = cell_of(j);
          ++start[cell_of_particle[j] + 1];
        }
        for (std::size_t c = 1; c < start.size(); ++c) start[c] += start[c - 1];
        std::vector<std::uint32_t>& fill = m.fill;
        fill.assign(start.begin(), start.end() - 1);
        order.resize(count);
        for (std::uint32_t j = 0; j < count; ++j) order[fill[cell_of_particle[j]]++] = j;
      };
      // Where the frame's box holds few enough cells of side `cell`, and `cell` is below 2048, each
      // search reads exactly its candidates' cells, the 3x3x3 around its home, as runs along z of
      // this frame's particles sorted by cell (skipping those farther than the worst distance kept),
      // and measures them in float in loops the compiler vectorises: the FLIP pour's encode is
      // 1.4x as fast as through the half-size cells below, with the same pairs. The floats are
      // exact: coordinates are below 2^24, a difference within the 3x3x3 is below 4096 and its
      // square below 2^24, and a sum that can be within the reach (below 2^23) has only exact partial
      // sums (a larger one rounds to 2^24 or more).
      std::int64_t c0[3], cdims[3];
      double cells = 1;
      for (int a = 0; a < 3; ++a) {
        c0[a] = floordiv(lo[a], cell);
        cdims[a] = floordiv(hi[a], cell) - c0[a] + 1;
        cells *= double(cdims[a]);
      }
      if (cell < 2048 && cells <= most_cells) {
        if (!prepared) {
          by_cell(
              std::size_t(cells), n,
              [&](std::uint32_t j) {
                const std::int64_t* q = &at[std::size_t(j) * 6 + 3];
                return std::size_t(((q[0] - c0[0]) * cdims[1] + (q[1] - c0[1])) * cdims[2] + (q[2] - c0[2]));
              },
              start, order);
          xs.resize(n), ys.resize(n), zs.resize(n), e.resize(n);
          for (std::uint32_t t = 0; t < n; ++t) {
            const std::int64_t* q = &at[std::size_t(order[t]) * 6];
            xs[t] = static_cast<float>(q[0]);
            ys[t] = static_cast<float>(q[1]);
            zs[t] = static_cast<float>(q[2]);
          }
        }
        // The previous particles by home cell (outside the box: its nearest), so that searches one
        // after another read the same cells (a sample is searched in its own order).
        const auto home_of = [&](std::uint32_t i, int a) { return floordiv(from(i, a), cell) - c0[a]; };
        std::vector<std::uint32_t>&visit_start = m.visit_start, &visit = m.visit;
        if (in_cell_order) {
          by_cell(
              std::size_t(cells), searched,
              [&](std::uint32_t u) {
                std::int64_t c[3];
                for (int a = 0; a < 3; ++a) c[a] = std::clamp<std::int64_t>(home_of(previous[u], a), 0, cdims[a] - 1);
                return std::size_t((c[0] * cdims[1] + c[1]) * cdims[2] + c[2]);
              },
              visit_start, visit);
        } else {
          visit.resize(searched);
          std::iota(visit.begin(), visit.end(), 0u);
        }
        // The 3x3x3 as runs of cells along z (x and y offsets, first and last z offset): the home
        // cell first, so that the 8 kept are near soon and few candidates after them are kept.
        constexpr int kRuns[11][4] = {{0, 0, 0, 0},   {0, 0, -1, -1}, {0, 0, 1, 1},  {-1, 0, -1, 1},
                                      {1, 0, -1, 1},  {0, -1, -1, 1}, {0, 1, -1, 1}, {-1, -1, -1, 1},
                                      {-1, 1, -1, 1}, {1, -1, -1, 1}, {1, 1, -1, 1}};
        // The arrays as local pointers: a store through `kept` (bytes) might, for the compiler,
        // change anything reached through this lambda's references, and the loop below would
        // reload them (the FLIP pour's cook took 3 % longer).
        const float *const px = xs.data(), *const py = ys.data(), *const pz = zs.data();
        std::int32_t* const pe = e.data();
        const std::uint32_t *const pstart = start.data(), *const porder = order.data();
        const std::uint32_t* const where[3] = {was[0], was[1], was[2]};
        const std::int32_t* const shift = moved;
        Pair* const pslots = slots.data();
        std::uint8_t* const pkept = kept.data();
        const std::int64_t side = cell, most = reach;
        // A search first reads only the candidates within twice the squared distance of the last
        // search's 8th (the searches go cell by cell, so neighbours' are alike), and again within
        // the reach when that finds fewer than 8. Those it skipped are farther than the 8 it kept,
        // so the pairs are the same; the FLIP pour's matching took 4-5 % less time (medians of five
        // alternating cooks: 87.0 against 91.1 ms).
        auto guess = static_cast<std::int32_t>(most);
        // The kept candidates as distance << 32 | current index: one comparison orders them as
        // (distance, index) does (distances within the reach are below 2^23).
        std::uint64_t best[kCandidates];
        int found = 0;
        // Where the last search was from. Previous particles at one place (a crowd parked at an
        // emitter) follow one another in the visit order and would each find the same candidates
        // (unless a search stops at kMostRead reads): each after the first takes the last search's
        // without one (3,000 of them read 2,501 candidates each a frame: "A crowd that moves as
        // one" in the experiments).
        std::int64_t last[3] = {0, 0, 0};
        bool searched = false;
        for (const std::uint32_t u : visit) {
          const std::uint32_t i = previous[u];
          float p[3];
          std::int64_t q[3], home[3], gap[3][3];  // gap[a][d + 1]: squared, to the cells d along axis a
          for (int a = 0; a < 3; ++a) {
            q[a] = static_cast<std::int32_t>(where[a][i]) +
                   (shift == nullptr ? 0 : shift[std::size_t(i) * 3 + std::size_t(a)]);
            p[a] = static_cast<float>(q[a]);
            home[a] = floordiv(q[a], side) - c0[a];
            const std::int64_t into = q[a] - (home[a] + c0[a]) * side;  // 0..cell-1
            gap[a][0] = (into + 1) * (into + 1);
            gap[a][1] = 0;
            gap[a][2] = (side - into) * (side - into);
          }
          const bool again = searched && q[0] == last[0] && q[1] == last[1] && q[2] == last[2];
          std::int32_t within = 0;  // the scan's bound, then the worst distance kept
          const auto scan = [&](std::int32_t bound) {
            found = 0;
            within = bound;
            std::uint32_t unread = kMostRead;
            for (const auto& run : kRuns) {
              // Runs, and a run's end cells, farther from the particle than the worst distance kept
              // cannot hold a closer candidate.
              const std::int64_t x = home[0] + run[0], y = home[1] + run[1];
              const std::int64_t row_gap = gap[0][run[0] + 1] + gap[1][run[1] + 1], limit = std::int64_t(within);
              if (x < 0 || x >= cdims[0] || y < 0 || y >= cdims[1] || row_gap > limit) continue;
              const int first = run[2] == -1 && row_gap + gap[2][0] > limit ? 0 : run[2];
              const int last = run[3] == 1 && row_gap + gap[2][2] > limit ? 0 : run[3];
              const std::int64_t z0 = std::max<std::int64_t>(home[2] + first, 0);
              const std::int64_t z1 = std::min(home[2] + last, cdims[2] - 1);
              if (first > last || z0 > z1) continue;
              const std::size_t k = std::size_t((x * cdims[1] + y) * cdims[2] + z0);
              const std::uint32_t t0 = pstart[k], t1 = t0 + std::min(pstart[k + std::size_t(z1 - z0) + 1] - t0, unread);
              unread -= t1 - t0;
              for (std::uint32_t t = t0; t < t1; ++t) {
                const float dx = px[t] - p[0], dy = py[t] - p[1], dz = pz[t] - p[2];
                pe[t] = static_cast<std::int32_t>(dx * dx + dy * dy + dz * dz);  // below 3 x 4096^2
              }
              // The candidates within the bound, 64 at a time as bits of a mask (4 compared at once
              // with SSE2), then kept one after another: a branch on each candidate's distance went
              // either way unpredictably, and the FLIP pour's encode took 1.07x as long (28.2 against
              // 30.3 MB/s, medians of four alternating runs of `bench codec`; the same pairs). A
              // candidate that passed against a bound that has shrunk since is refused by
              // keep_nearest(), which compares with the worst kept.
              for (std::uint32_t t = t0; t < t1; t += 64) {
                const std::uint32_t end = std::min(t1, t + 64);
                std::uint64_t pass = 0;
                std::uint32_t u = t;
#if defined(__SSE2__)
                const __m128i limit4 = _mm_set1_epi32(within);
                for (; u + 4 <= end; u += 4) {
                  const __m128i d = _mm_loadu_si128(reinterpret_cast<const __m128i*>(pe + u));
                  const int over = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpgt_epi32(d, limit4)));
                  pass |= std::uint64_t(~over & 15) << (u - t);
                }
#endif
                for (; u < end; ++u) pass |= std::uint64_t(pe[u] <= within) << (u - t);
                for (; pass != 0; pass &= pass - 1) {
                  const std::uint32_t v = t + static_cast<std::uint32_t>(std::countr_zero(pass));
                  keep_nearest(best, found, std::uint64_t(pe[v]) << 32 | porder[v]);
                  if (found == kCandidates) within = static_cast<std::int32_t>(best[kCandidates - 1] >> 32);
                }
              }
            }
          };
          if (!again) {
            scan(guess);
            if (found < kCandidates && guess < most) scan(static_cast<std::int32_t>(most));
            guess = found == kCandidates
                        ? static_cast<std::int32_t>(std::min<std::int64_t>(most, 2 * std::int64_t(within) + 1))
                        : static_cast<std::int32_t>(most);
            std::copy_n(q, 3, last);
            searched = true;
          }
          for (int b = 0; b < found; ++b) {
            pslots[std::size_t(i) * kCandidates + std::size_t(b)] =
                Pair{std::int64_t(best[b] >> 32), i, static_cast<std::uint32_t>(best[b])};
          }
          pkept[i] = static_cast<std::uint8_t>(found);
        }
      } else {
        // Otherwise (sparse frames, or grid steps much finer than the spacing) a dense grid of cells
        // of half the candidates' side (a liquid fills a small part of its box, so a side-`cell`
        // cell holds about ten particles), or of their side, visited nearest first until the 8 kept
        // are closer than any cell left; a cell's particles are one range found by indexing.
        std::int64_t side = std::max<std::int64_t>(1, cell / 2), g0[3], dims[3];
        double total = 1;
        for (int pass = 0; pass < 2; ++pass) {
          total = 1;
          for (int a = 0; a < 3; ++a) {
            g0[a] = floordiv(lo[a], side);
            dims[a] = floordiv(hi[a], side) - g0[a] + 1;
            total *= double(dims[a]);
          }
          if (total <= most_cells || side == cell) break;
          side = cell;
        }
        if (total <= most_cells) {
          const auto index = [&](const std::int64_t* q) {
            return std::size_t(((floordiv(q[0], side) - g0[0]) * dims[1] + (floordiv(q[1], side) - g0[1])) * dims[2] +
                               (floordiv(q[2], side) - g0[2]));
          };
          if (!prepared) {
            // This frame's particles in cell order, their positions and cells copied beside them.
            by_cell(
                std::size_t(total), n, [&](std::uint32_t j) { return index(&at[std::size_t(j) * 6]); }, start, order);
            sorted.resize(std::size_t(n) * 6);
            for (std::uint32_t t = 0; t < n; ++t)
              std::copy_n(&at[std::size_t(order[t]) * 6], 6, &sorted[std::size_t(t) * 6]);
            // Cell offsets by the least squared distance a particle in one can be from a particle in
            // the other (whole cells between them), up to the reach.
            const int far = static_cast<int>(std::sqrt(double(reach)) / double(side)) + 2;
            for (int x = -far; x <= far; ++x)
              for (int y = -far; y <= far; ++y)
                for (int z = -far; z <= far; ++z) {
                  std::int64_t bound = 0;
                  for (int d : {x, y, z}) {
                    const std::int64_t gap = std::int64_t(std::max(0, std::abs(d) - 1)) * side;  // cells between
                    bound += gap * gap;
                  }
                  if (bound <= reach) offsets.push_back({bound, {x, y, z}});
                }
            std::stable_sort(offsets.begin(), offsets.end(),
                             [](const Offset& u, const Offset& v) { return u.bound < v.bound; });
          }
          // The previous particles by cell (outside the box: its nearest cell), so that searches one
          // after another visit the same cells.
          std::vector<std::uint32_t>&visit_start = m.visit_start, &visit = m.visit;
          const auto home_cell = [&](std::uint32_t u) {
            std::int64_t c[3];
            for (int a = 0; a < 3; ++a) {
              const std::int64_t v = from(previous[u], a);
              c[a] = std::clamp<std::int64_t>(floordiv(v, side) - g0[a], 0, dims[a] - 1);
            }
            return static_cast<std::size_t>((c[0] * dims[1] + c[1]) * dims[2] + c[2]);
          };
          if (in_cell_order) {
            by_cell(std::size_t(total), searched, home_cell, visit_start, visit);
          } else {
            visit.resize(searched);
            std::iota(visit.begin(), visit.end(), 0u);
          }
          for (const std::uint32_t u : visit) {
            search(previous[u],
                   [&](const std::int64_t* p, const std::int64_t*, const auto& consider, const auto& worst) {
                     const std::int64_t c[3] = {floordiv(p[0], side) - g0[0], floordiv(p[1], side) - g0[1],
                                                floordiv(p[2], side) - g0[2]};
                     for (const Offset& o : offsets) {
                       if (o.bound > worst()) break;
                       const std::int64_t x = c[0] + o.d[0], y = c[1] + o.d[1], z = c[2] + o.d[2];
                       if (x < 0 || x >= dims[0] || y < 0 || y >= dims[1] || z < 0 || z >= dims[2]) continue;
                       const std::size_t k = std::size_t((x * dims[1] + y) * dims[2] + z);
                       for (std::uint32_t t = start[k]; t < start[k + 1] && worst() >= 0; ++t)
                         consider(order[t], &sorted[std::size_t(t) * 6]);
                     }
                   });
          }
        } else {
          // Otherwise this frame's particles sorted by cell: a cell's particles are one range, found
          // by a binary search.
          if (!prepared) {
            sorted_cells.resize(n);
            for (std::uint32_t j = 0; j < n; ++j) {
              const std::int64_t* q = &at[std::size_t(j) * 6 + 3];
              sorted_cells[j] = {cell_key(q[0], q[1], q[2]), j};
            }
            std::sort(sorted_cells.begin(), sorted_cells.end());
          }
          for (const std::uint32_t i : previous) {
            search(i, [&](const std::int64_t*, const std::int64_t* home, const auto& consider, const auto& worst) {
              for (std::int64_t dx = -1; dx <= 1; ++dx)
                for (std::int64_t dy = -1; dy <= 1; ++dy)
                  for (std::int64_t dz = -1; dz <= 1; ++dz) {
                    const std::uint64_t k = cell_key(home[0] + dx, home[1] + dy, home[2] + dz);
                    auto it =
                        std::lower_bound(sorted_cells.begin(), sorted_cells.end(), std::pair{k, std::uint32_t{0}});
                    for (; it != sorted_cells.end() && it->first == k && worst() >= 0; ++it)
                      consider(it->second, &at[std::size_t(it->second) * 6]);
                  }
            });
          }
        }
      }
      prepared = true;
    };
    // The steps of the previous particles `previous` along their stored velocities.
    const auto step_along = [&](std::span<const std::uint32_t> previous) {
      steps.resize(std::size_t(previous_.count) * 3);
      for (const std::uint32_t i : previous)
        for (int a = 0; a < 3; ++a) steps[std::size_t(i) * 3 + std::size_t(a)] = velocity_step(i, a);
    };
    std::vector<std::uint32_t>& all = m.all;
    all.resize(previous_.count);
    std::iota(all.begin(), all.end(), 0u);
    // A previous particle with a current one at exactly its place (a FLIP inflow re-seeds its
    // particles where it seeded them: a fifth of the pour's, and more in its first frames) keeps
    // that one alone as its candidate, without a search: it is the nearest of the six a search
    // would keep, and the pairing below takes it first. Where several previous particles share a
    // place, each takes the next current one there, lowest index first, and those left without
    // one are searched, as the ones without are. The FLIP pour cooks to the same bytes, its
    // `[x y z scale]` encode 1.07-1.13x as fast (docs/compression-experiments.md, "Particles that
    // stay put, paired without a search"); a clip with none costs a table lookup a particle. (A
    // search keeps a particle's six nearest, ties by index: thousands of particles at one place
    // would all keep the same six, and all but a few would be left unpaired.)
    std::vector<std::uint32_t>& rest = m.rest;
    rest.clear();
    ExactPlaces& places = m.places;
    places.build(n, at.data());
    for (std::uint32_t i = 0; i < previous_.count; ++i) {
      const std::int64_t q[3] = {from(i, 0), from(i, 1), from(i, 2)};  // where it was (moved is null)
      const std::uint32_t j = places.take(q);
      if (j == ExactPlaces::kNone) {
        rest.push_back(i);
        continue;
      }
      slots[std::size_t(i) * kCandidates] = Pair{0, i, j};
      kept[i] = 1;
    }
    searches(rest, true);  // from where they were
    // A cache without ids whose particles persist (a particle system without its ids) moves them
    // further than their spacing: the nearest particle is another one, and the clip costs about
    // 4x what it does with ids. Moved on by their stored velocities they are found again; a FLIP
    // liquid's are not (its solver re-samples them: moved, they land no nearer). So on a sample of
    // up to kVelocitySample previous particles, the nearest candidates from both places are
    // compared, and the frame is matched from where they land nearer by more than half (in the
    // sum of squared distances).
    if (velocity_.present()) {
      // The encoder's own sample (playback's kMotionSample is another test, of a decoded pair).
      constexpr std::uint32_t kVelocitySample = 256;
      const std::uint32_t every = (previous_.count + kVelocitySample - 1) / kVelocitySample;
      std::vector<std::uint32_t>& sample = m.sample;
      sample.clear();
      for (std::uint32_t i = every / 2; i < previous_.count; i += every) sample.push_back(i);
      const auto cost = [&] {
        std::int64_t sum = 0;
        for (const std::uint32_t i : sample)
          sum += kept[i] != 0 ? slots[std::size_t(i) * kCandidates].distance : reach + 1;
        return sum;
      };
      const std::int64_t still = cost();
      std::vector<Pair>& saved = m.saved;
      std::vector<std::uint8_t>& saved_kept = m.saved_kept;
      saved.resize(sample.size() * kCandidates);
      saved_kept.resize(sample.size());
      for (std::size_t u = 0; u < sample.size(); ++u) {
        std::copy_n(&slots[std::size_t(sample[u]) * kCandidates], kCandidates, &saved[u * kCandidates]);
        saved_kept[u] = kept[sample[u]];
      }
      step_along(sample);
      moved = steps.data();
      searches(sample, false);
      if (2 * cost() < still) {
        step_along(all);
        moved = steps.data();
        searches(all, true);
      } else {
        for (std::size_t u = 0; u < sample.size(); ++u) {
          std::copy_n(&saved[u * kCandidates], kCandidates, &slots[std::size_t(sample[u]) * kCandidates]);
          kept[sample[u]] = saved_kept[u];
        }
        moved = nullptr;  // the pairs are from where the particles were
      }
    }
    // The pairs are taken closest first, ties by previous then current index, each previous and
    // current particle once. A previous particle whose nearest candidate has it as its own nearest (by distance, then
    // previous index) makes the first pair, in that order, of either: it is taken, and every later
    // pair of either would be passed over. Only the others' pairs are sorted (on the FLIP pour two
    // thirds of the particles pair this way, and a sixth of the candidate pairs are left).
    std::vector<std::uint8_t>& prev_taken = m.prev_taken;
    prev_taken.assign(previous_.count, 0);
    if (reach < (std::int64_t{1} << 32)) {                        // distance << 32 | index keys
      std::vector<std::uint64_t>& nearest_prev = m.nearest_prev;  // per current particle
      nearest_prev.assign(n, ~std::uint64_t{0});
      for (std::uint32_t i = 0; i < previous_.count; ++i) {
        for (std::uint32_t b = 0; b < kept[i]; ++b) {
          const Pair& pair = slots[std::size_t(i) * kCandidates + b];
          nearest_prev[pair.cur] = std::min(nearest_prev[pair.cur], std::uint64_t(pair.distance) << 32 | i);
        }
      }
      for (std::uint32_t i = 0; i < previous_.count; ++i) {
        if (kept[i] == 0) continue;
        const Pair& first = slots[std::size_t(i) * kCandidates];
        if (nearest_prev[first.cur] != (std::uint64_t(first.distance) << 32 | i)) continue;
        prev_taken[i] = 1;
        match[first.cur] = i;
      }
    }
    // The rest: the pairs were made in previous-index order, each particle's by (distance, current
    // index), so a stable sort by distance is that order. Every distance is within the reach, so
    // the depth sorter's radix sort does it (a comparison sort here was about 15 % of a FLIP cook).
    std::vector<Pair>& pairs = m.pairs;
    pairs.clear();
    for (std::uint32_t i = 0; i < previous_.count; ++i) {
      if (prev_taken[i]) continue;
      for (std::uint32_t b = 0; b < kept[i]; ++b) {
        const Pair& pair = slots[std::size_t(i) * kCandidates + b];
        if (match[pair.cur] < 0) pairs.push_back(pair);
      }
    }
    take_closest_first(pairs, reach, match, [&](std::uint32_t j) { return match[j] < 0 ? j : ExactPlaces::kNone; });
    // Particles that persist (matched along their velocities) are born and die: what is left over
    // is not one particle in both frames, and paired it would jump from one to the other.
    if (moved == nullptr) pair_leftovers(n, cell, reach, from, match);
  }

 private:
  using Scratch = PositionMatcher::Scratch;

  // Previous particle i's stored velocity over a frame on axis a, in grid steps (bounded: a step
  // beyond any grid finds no candidates).
  std::int32_t velocity_step(std::uint32_t i, int a) const {
    const auto axis = std::size_t(a);
    const double velocity = dequantize(velocity_.q[axis][i], velocity_.step[axis], velocity_.origin[axis]);
    const double steps = velocity * velocity_.frame_seconds / velocity_.position_step[axis];
    constexpr double kFar = 1 << 24;
    return static_cast<std::int32_t>(std::llround(std::clamp(steps, -kFar, kFar)));
  }

  // Takes `pairs` closest first, each previous and current particle once (the previous ones marked
  // in prev_taken, the current ones' matches set). The pairs are made in previous-index order,
  // each particle's by (distance, current index), so a stable sort by distance is (distance,
  // previous, current) order. Every distance is within the reach, so the depth sorter's radix sort
  // does it (a comparison sort here was about 15 % of a FLIP cook).
  // `unpaired(cur)` is the current particle a pair with `cur` pairs (kNone once there is none):
  // `cur` itself while it is unpaired, or in pair_leftovers() the next one at its place.
  template <class Unpaired>
  void take_closest_first(const std::vector<Pair>& pairs, std::int64_t reach, std::vector<std::int64_t>& match,
                          const Unpaired& unpaired) {
    Scratch& m = scratch_;
    std::vector<std::uint32_t>& by_distance = m.by_distance;
    by_distance.resize(pairs.size());
    if (reach < (std::int64_t{1} << 32) && pairs.size() < (std::size_t{1} << 32)) {
      std::vector<std::uint64_t>&items = m.items, &scratch = m.scratch;
      items.resize(pairs.size());
      scratch.resize(pairs.size());
      for (std::size_t t = 0; t < pairs.size(); ++t) items[t] = std::uint64_t(pairs[t].distance) << 32 | t;
      const auto radix = reach < (std::int64_t{1} << 16) ? sort::radix_sort_pairs16 : sort::radix_sort_pairs;
      radix(items.data(), scratch.data(), items.size(), by_distance.data());
    } else {
      std::iota(by_distance.begin(), by_distance.end(), 0u);
      std::stable_sort(by_distance.begin(), by_distance.end(),
                       [&](std::uint32_t x, std::uint32_t y) { return pairs[x].distance < pairs[y].distance; });
    }
    for (const std::uint32_t t : by_distance) {
      const Pair& pair = pairs[t];
      if (m.prev_taken[pair.prev]) continue;
      const std::uint32_t cur = unpaired(pair.cur);
      if (cur == ExactPlaces::kNone) continue;
      m.prev_taken[pair.prev] = 1;
      match[cur] = pair.prev;
    }
  }

  // The particles left over by the pairing of plain positions (a liquid's re-sampled particles),
  // paired among themselves within the same reach, closest first. A previous particle is left
  // over when closer pairs took each of its kCandidates nearest; a current one when no previous
  // particle kept it. Each round pairs each leftover with its kCandidates nearest remaining
  // current particles (the closest of all those pairs is always made), until a round finds none
  // within the reach or kLeftoverRounds have run (the FLIP pour needs 3 or 4). They are looked for
  // in the 2x2x2 cells of twice the side nearest each previous particle, which reach at least
  // `cell` from it on every side as the 3x3x3 around its home cell do (8 lookups a particle where
  // there were 27, and take_closest_first()'s radix sort, took this from 340 to 225 us a frame of
  // the pour, about a tenth of its encode).
  //
  // Each such pair would otherwise be a drop and a new particle. On the FLIP pour a tenth of the
  // previous particles were left over (337 a frame of 3,431): their drops split the survivors into
  // runs of 11 and cost the decoder a branch it mispredicts per run and coded word, and a new
  // particle costs about what a survivor's larger residual does. Paired, the pour has 54 operations
  // a frame instead of 262, is 2.9 % smaller and decodes about 1.4x as fast (docs/compression-experiments.md,
  // "The leftovers paired").
  //
  // Current particles that share a place are one candidate here, which pairs the lowest of them
  // still unpaired, so that a crowd at one place fills one of a search's kCandidates, not all of
  // them. A crowd that moves as one (particles parked at an emitter that moves) was otherwise left
  // unpaired but for a few a frame: every search kept the same kCandidates of it, ties by index
  // ("A crowd that moves as one" in the experiments).
  static constexpr int kLeftoverRounds = 16;
  static constexpr std::uint32_t kLeftoverReads = 64;
  template <class From>
  void pair_leftovers(std::uint32_t n, std::int64_t cell, std::int64_t reach, const From& from,
                      std::vector<std::int64_t>& match) {
    Scratch& m = scratch_;
    const std::int64_t side = 2 * cell;
    std::vector<Spare>& spare = m.spare;
    spare.clear();
    ExactPlaces& places = m.places;
    places.restart();
    std::vector<std::uint64_t>& place_of = m.place_of;  // a place's first unpaired index: its slot
    place_of.resize(n);
    // The current particle that a candidate `j` (a place's first unpaired particle) pairs now.
    const auto unpaired = [&](std::uint32_t j) { return places.first_unpaired(place_of[j], match); };
    for (std::uint32_t j = 0; j < n; ++j) {
      if (match[j] >= 0) continue;
      const std::int64_t* q = &m.at[std::size_t(j) * 6];
      const std::uint64_t h = places.probe(q);
      if (places.first_unpaired(h, match) != j) continue;  // an earlier one stands for its place
      place_of[j] = h;
      spare.push_back(
          Spare{cell_key(floordiv(q[0], side), floordiv(q[1], side), floordiv(q[2], side)), {q[0], q[1], q[2]}, j});
    }
    std::sort(spare.begin(), spare.end());
    std::vector<std::uint32_t>& left = m.left;  // the previous particles left over
    left.clear();
    for (std::uint32_t i = 0; i < previous_.count; ++i)
      if (!m.prev_taken[i]) left.push_back(i);
    std::vector<Pair>& pairs = m.pairs;
    CellRanges& cells = m.spare_cells;
    // Candidates read in all rounds, at most kLeftoverReads a particle of the frame.
    const std::uint64_t budget = std::uint64_t(kLeftoverReads) * n;
    std::uint64_t read = 0;
    // A search that read its cells whole and kept fewer than kCandidates found every current
    // particle within the reach of it: later rounds take those of its candidates still left over
    // (current particles only leave `spare`), the same pairs its search would find, without
    // searching again, and one that found none is dropped. `known[i]` is then 1 + its count of
    // candidates, kept in its slots (the pairing before no longer needs them). At the pour's
    // resolution 120 the later rounds had made 45 % of the reads, nearly all finding nothing: its
    // encode is about 1.07x as fast (docs/compression-experiments.md, "The leftovers' complete
    // searches kept").
    std::vector<std::uint8_t>& known = m.known;
    known.assign(previous_.count, 0);
    Pair* const slots = m.slots.data();
    for (int round = 0; round < kLeftoverRounds && !left.empty() && !spare.empty() && read < budget; ++round) {
      cells.build(spare);
      pairs.clear();
      for (const std::uint32_t i : left) {
        if (known[i] != 0) {
          for (int b = 0; b < known[i] - 1; ++b) {
            const Pair& pair = slots[std::size_t(i) * kCandidates + std::size_t(b)];
            if (unpaired(pair.cur) != ExactPlaces::kNone) pairs.push_back(pair);
          }
          continue;
        }
        if (read == budget) break;
        const std::int64_t p[3] = {from(i, 0), from(i, 1), from(i, 2)};
        std::int64_t first[3];  // the 2x2x2 cells' lowest corner: the particle in the nearer half of its cell
        for (int a = 0; a < 3; ++a) {
          const std::int64_t c = floordiv(p[a], side);
          first[a] = p[a] - c * side < cell ? c - 1 : c;
        }
        std::pair<std::int64_t, std::uint32_t> best[kCandidates];  // (distance, current index)
        int found = 0;
        const auto most = static_cast<std::uint32_t>(std::min<std::uint64_t>(kMostRead, budget - read));
        std::uint32_t unread = most;
        for (int d = 0; d < 8 && unread > 0; ++d) {
          auto [t0, t1] = cells.find(cell_key(first[0] + (d & 1), first[1] + (d >> 1 & 1), first[2] + (d >> 2)));
          t1 = t0 + std::min(t1 - t0, unread);
          unread -= t1 - t0;
          for (std::uint32_t t = t0; t < t1; ++t) {
            const std::int64_t e = squared_distance(spare[t].q, p);
            if (e <= reach) keep_nearest(best, found, std::pair{e, spare[t].j});
          }
        }
        for (int b = 0; b < found; ++b) pairs.push_back(Pair{best[b].first, i, best[b].second});
        if (unread > 0 && found < kCandidates) {
          known[i] = static_cast<std::uint8_t>(1 + found);
          for (int b = 0; b < found; ++b) slots[std::size_t(i) * kCandidates + std::size_t(b)] = pairs.end()[b - found];
        }
        read += most - unread;
      }
      if (pairs.empty()) break;
      take_closest_first(pairs, reach, match, unpaired);
      std::erase_if(left, [&](std::uint32_t i) { return m.prev_taken[i] != 0 || known[i] == 1; });
      std::erase_if(spare, [&](const Spare& c) { return unpaired(c.j) == ExactPlaces::kNone; });
    }
  }

  Scratch& scratch_;
  const GridPoints& previous_;
  const GridPoints& current_;
  const GridVelocity& velocity_;
};

}  // namespace

PositionMatcher::PositionMatcher() : scratch_(std::make_unique<Scratch>()) {}
PositionMatcher::~PositionMatcher() = default;

void PositionMatcher::match(const GridPoints& previous, const GridVelocity& velocity, const GridPoints& current,
                            std::vector<std::int64_t>& match) {
  Matching(*scratch_, previous, velocity, current).run(match);
}

}  // namespace pstream::format::particle
