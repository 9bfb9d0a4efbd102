// Particles from an Alembic archive: one points object, a mesh's vertices, or every points
// object merged; positions baked into world space with the object's transform hierarchy.
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

#include <fmt/format.h>
#include <xxhash.h>

#include "cook/source.hpp"
#include "particlestream/alembic.hpp"

namespace pstream::cook {
namespace {

using namespace pstream::alembic;

bool is_identity(const Matrix44& m) { return m == identity_matrix(); }

// Uniform scale of a transform: the cube root of its 3x3 determinant's magnitude.
double uniform_scale(const Matrix44& m) {
  const double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                     m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                     m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  return std::cbrt(std::abs(det));
}

// A float geometry parameter at `time`, one value per particle (constant scope is broadcast).
// Writes them into `out` from element `base` on.
void expand_param(const GeomParam& p, double time, std::uint64_t count, const std::string& where,
                  std::vector<float>& out, std::uint64_t base) {
  if (p.values().header().num_samples == 0)
    throw Error(fmt::format("{}: parameter '{}' has no samples", where, p.name()));
  const SampleView vals = p.values().sample_at(time).first;
  if (!pod_is_float(vals.pod()) && !pod_is_integer(vals.pod())) {
    throw Error(fmt::format("{}: parameter '{}' is {}, not a number", where, p.name(), pod_name(vals.pod())));
  }
  const std::size_t extent = vals.extent();
  std::vector<std::uint64_t> index;  // indexed params: which value each element takes
  std::uint64_t elements = vals.size();
  if (p.indexed()) {
    const SampleView idx = p.indices().sample_at(time).first;
    elements = idx.scalar_count();
    index.resize(elements);
    for (std::uint64_t i = 0; i < elements; ++i) {
      index[i] = idx.value_u64(i);
      if (index[i] >= vals.size()) {
        throw Error(fmt::format("{}: parameter '{}' index {} points past its {} values", where, p.name(), index[i],
                                vals.size()));
      }
    }
  }
  if (elements != count && elements != 1) {
    throw Error(fmt::format("{}: parameter '{}' has {} values for {} particles", where, p.name(), elements, count));
  }
  ensure_size(out, (base + count) * extent);
  float* dst = out.data() + base * extent;
  const auto value = [&](std::uint64_t element, std::size_t c) {
    const std::uint64_t k = p.indexed() ? index[element] : element;
    return static_cast<float>(vals.value_f64(k * extent + c));
  };
  if (elements == 1) {
    for (std::uint64_t i = 0; i < count; ++i) {
      for (std::size_t c = 0; c < extent; ++c) dst[i * extent + c] = value(0, c);
    }
  } else if (!p.indexed() && vals.pod() == Pod::Float32) {
    vals.copy_raw(std::as_writable_bytes(std::span(dst, count * extent)));
  } else {
    for (std::uint64_t i = 0; i < count; ++i) {
      for (std::size_t c = 0; c < extent; ++c) dst[i * extent + c] = value(i, c);
    }
  }
}

struct Cooked {
  Object object;
  std::optional<Points> points;
  std::optional<PolyMesh> mesh;
  const TimeSampling& sampling() const { return points ? points->time_sampling() : mesh->time_sampling(); }
  std::uint32_t samples() const { return points ? points->num_samples() : mesh->num_samples(); }
  const GeomParam* param(const std::string& name) const {
    if (points) return points->find_param(name);
    return nullptr;
  }
};

Archive::Fetched fetch_progress(const std::function<void(const Progress&)>& progress) {
  if (!progress) return {};
  return [progress](std::uint64_t done, std::uint64_t total) {
    Progress p;
    p.stage = Stage::Fetch;
    p.bytes_in = done;
    p.bytes_total = total;
    progress(p);
  };
}

class AlembicSource final : public Source {
 public:
  AlembicSource(const Options& options, const std::function<void(const Progress&)>& progress)
      : archive_(Archive::open(options.input, fetch_progress(progress))) {
    const std::string file = options.input.string();
    if (!options.object.empty()) {
      const auto o = archive_.find(options.object);
      if (!o) throw Error(fmt::format("{}: no object '{}'{}", file, options.object, object_list()));
      if (Points::matches(*o)) {
        objects_.push_back({*o, Points(*o), std::nullopt});
      } else if (PolyMesh::matches(*o)) {
        objects_.push_back({*o, std::nullopt, PolyMesh(*o)});  // its vertices, cooked as points
      } else {
        const std::string_view kind = object_kind(*o);
        const bool vowel = !kind.empty() && std::string_view("aeioux").find(kind[0]) != std::string_view::npos;
        throw Error(fmt::format("{}: '{}' is {} {} object, not points or a mesh{}", file, options.object,
                                vowel ? "an" : "a", kind, object_list()));
      }
    } else {
      for (const Object& o : archive_.objects()) {
        if (Points::matches(o)) objects_.push_back({o, Points(o), std::nullopt});
      }
      if (objects_.empty()) {
        // No points: a mesh's vertices, as some exporters write particles (Blender's Alembic
        // exporter among them), when there is exactly one mesh to choose.
        std::vector<Object> meshes;
        for (const Object& o : archive_.objects()) {
          if (PolyMesh::matches(o)) meshes.push_back(o);
        }
        if (meshes.empty()) throw Error(fmt::format("{}: the archive holds no points objects{}", file, object_list()));
        if (meshes.size() > 1) {
          throw OptionError("object", fmt::format("{}: the archive holds no points objects, and {} meshes; choose "
                                                  "one with `object` (its full name) to cook its vertices{}",
                                                  file, meshes.size(), object_list()));
        }
        objects_.push_back({meshes.front(), std::nullopt, PolyMesh(meshes.front())});
      }
      if (objects_.size() > 1 && !options.merge) {
        throw OptionError("object",
                          fmt::format("{}: {} points objects; choose one with `object` (its full name), or cook "
                                      "them together with `merge`{}",
                                      file, objects_.size(), object_list()));
      }
    }
    for (const Cooked& c : objects_) {
      if (c.samples() == 0) throw Error(fmt::format("{}: object '{}' has no samples", file, c.object.full_name()));
    }
  }

  std::string name() const override { return archive_.name(); }
  bool mesh_vertices() const override {
    return std::any_of(objects_.begin(), objects_.end(), [](const Cooked& c) { return c.mesh.has_value(); });
  }
  std::string object() const override {
    std::string s;
    for (const Cooked& c : objects_) s += (s.empty() ? "" : ",") + c.object.full_name();
    return s;
  }
  double default_fps() const override {
    const TimeSampling& ts = objects_.front().sampling();
    if (ts.type == TimeSamplingType::Uniform) return 1.0 / ts.time_per_cycle;
    const double dcc = archive_.info().dcc_fps;
    return dcc > 0 ? dcc : 24.0;
  }
  double start_time() const override {
    double t = std::numeric_limits<double>::max();
    for (const Cooked& c : objects_) t = std::min(t, c.sampling().sample_time(0));
    return t;
  }
  double end_time() const override {
    double t = -std::numeric_limits<double>::max();
    for (const Cooked& c : objects_) t = std::max(t, c.sampling().sample_time(c.samples() - 1));
    return t;
  }
  std::uint64_t input_bytes() const override { return archive_.file_size(); }
  bool has_widths() const override {
    return std::all_of(objects_.begin(), objects_.end(),
                       [](const Cooked& c) { return c.points && c.points->widths(); });
  }
  bool has_color() const override {
    return std::all_of(objects_.begin(), objects_.end(), [](const Cooked& c) { return c.param("Cd") != nullptr; });
  }
  bool has_velocity() const override {
    return std::all_of(objects_.begin(), objects_.end(), [](const Cooked& c) {
      return c.points ? c.points->has_velocities() : c.mesh->has_velocities();
    });
  }
  // Ids that can be used: the property exists and holds one id per particle. Some exporters
  // (Blender's FLIP liquids) write an empty .pointIds in every sample: that is no ids.
  bool has_ids() const override {
    return std::all_of(objects_.begin(), objects_.end(), [](const Cooked& c) {
      if (!c.points || !c.points->has_ids()) return false;
      for (std::uint32_t s = 0; s < c.samples(); ++s) {
        const std::uint64_t n = c.points->positions(s).size();
        if (n != 0) return c.points->ids(s).size() == n;
      }
      return true;
    });
  }
  std::string why_no_ids() const override {
    for (const Cooked& c : objects_) {
      if (!c.points || !c.points->has_ids()) {
        return fmt::format("the cache has no particle ids ('{}' has no .pointIds)", c.object.full_name());
      }
    }
    return "the cache has no particle ids (its .pointIds are empty in every sample, as Blender writes FLIP liquids)";
  }
  std::vector<std::filesystem::path> files() const override { return {archive_.name()}; }
  void check_intact() const override { archive_.check_intact(); }
  std::uint64_t content_hash() const override {
    const auto bytes = archive_.bytes();
    const std::uint64_t h = XXH3_64bits(bytes.data(), bytes.size());
    archive_.check_intact();
    return h;
  }
  std::uint32_t float_components(const std::string& name) const override {
    std::uint32_t components = 0;
    for (const Cooked& c : objects_) {
      const GeomParam* p = c.param(name);
      if (p == nullptr) return 0;
      components = p->values().header().extent;
    }
    return components;
  }

  bool read_direct(double time, const Request& request, DirectFrame& out) override {
    if (objects_.size() != 1 || !objects_[0].points || request.interpolate || request.color || request.velocity ||
        request.id || !request.floats.empty() || request.scale_from == ScaleFrom::Attribute) {
      return false;
    }
    const Cooked& c = objects_[0];
    const auto index = static_cast<std::uint32_t>(c.sampling().near_index(time, c.samples()).first);
    const SampleView P = c.points->positions(index);
    out.count = P.size();
    out.positions = P.bytes().data();
    if (!ids_fit(c, index, out.count)) return false;  // the general path names the sample
    const Matrix44 m = request.bake_xforms ? parent_world_matrix(c.object, time) : identity_matrix();
    out.identity = is_identity(m);
    out.matrix = m;
    out.widths = nullptr;
    if (request.scale_from == ScaleFrom::Constant) {
      out.constant_scale = request.scale_constant;
      return true;
    }
    // A transform that scales also scales widths: the general path does that arithmetic.
    if (!out.identity && uniform_scale(m) != 1.0) return false;
    const GeomParam* w = c.param("widths");
    if (w == nullptr || w->indexed() || w->values().header().num_samples == 0) return false;
    const SampleView widths = w->values().sample_at(c.sampling().sample_time(index)).first;
    if (widths.pod() != Pod::Float32 || widths.extent() != 1 || widths.size() != out.count)
      return false;  // general path
    // Widths that are NaN, infinite or negative: the general path names them (or drops them).
    const std::span<const std::byte> bytes = widths.bytes();
    for (std::size_t i = 0; i < out.count; ++i) {
      float w;
      std::memcpy(&w, bytes.data() + i * 4, 4);
      if (!(w >= 0.0f && w <= std::numeric_limits<float>::max())) return false;
    }
    out.widths = bytes.data();
    return true;
  }

  // Without ids, interpolation moves the nearest sample along its velocities (when it has some).
  bool can_interpolate() const override { return has_ids() || has_velocity(); }
  std::string why_no_interpolation() const override {
    return why_no_ids() +
           ", and no velocities: interpolation matches particles by id, or moves them along their velocities. Cook "
           "without `interpolate`: each frame takes the nearest sample";
  }

  void read(double time, const Request& request, ParticleFrame& out) override {
    if (request.interpolate && !ids_known_) {
      ids_usable_ = has_ids();
      ids_known_ = true;
    }
    for (const Cooked& c : objects_) {
      const TimeSampling& ts = c.sampling();
      if (request.interpolate && !ids_usable_) {
        advect_nearest(c, time, request, out);
        continue;
      }
      if (!request.interpolate) {
        read_sample(c, static_cast<std::uint32_t>(ts.near_index(time, c.samples()).first), time, request, out);
        continue;
      }
      const auto [a, ta] = ts.floor_index(time, c.samples());
      const auto [b, tb] = ts.ceil_index(time, c.samples());
      if (a == b || tb <= ta) {
        read_sample(c, static_cast<std::uint32_t>(a), time, request, out);
        continue;
      }
      blend(c, static_cast<std::uint32_t>(a), static_cast<std::uint32_t>(b), (time - ta) / (tb - ta), time, request,
            out);
    }
  }

 private:
  std::string object_list() const {
    std::string s;
    for (const Object& o : archive_.objects()) s += fmt::format("\n  {} ({})", o.full_name(), object_kind(o));
    return s.empty() ? "" : "; its objects:" + s;
  }

  // Ids hold one id per particle, or none (Blender's FLIP liquids write none), whether or not the
  // cook keeps them: a sample that says otherwise is malformed.
  static bool ids_fit(const Cooked& c, std::uint32_t index, std::uint64_t n) {
    if (!c.points || !c.points->has_ids()) return true;
    const std::uint64_t ids = c.points->ids(index).size();
    return ids == 0 || ids == n;
  }

  // Appends sample `index` of one object; positions (and velocities) baked with the world
  // transform at `time`.
  void read_sample(const Cooked& c, std::uint32_t index, double time, const Request& request, ParticleFrame& out) {
    const std::string where = fmt::format("{}: {} sample {}", archive_.name(), c.object.full_name(), index);
    const double sample_time = c.sampling().sample_time(index);
    const SampleView P = c.points ? c.points->positions(index) : c.mesh->positions(index);
    const std::uint64_t n = P.size();
    const std::uint64_t base = out.count;
    out.count += n;
    const Matrix44 m = request.bake_xforms ? parent_world_matrix(c.object, time) : identity_matrix();
    const bool identity = is_identity(m);

    if (!ids_fit(c, index, n)) {
      throw Error(fmt::format("{}: {} ids for {} particles (.pointIds must hold one id per particle, or none)", where,
                              c.points->ids(index).size(), n));
    }
    ensure_size(out.position, out.count * 3);
    float* pos = out.position.data() + base * 3;
    P.copy_raw(std::as_writable_bytes(std::span(pos, n * 3)));
    if (!identity) transform_points(m, pos, n, true);

    // Scale (a radius): widths are diameters.
    const double size_factor = identity ? 1.0 : uniform_scale(m);
    if (request.scale_from == ScaleFrom::Constant) {
      ensure_size(out.scale, out.count);
      std::fill(out.scale.begin() + static_cast<std::ptrdiff_t>(base),
                out.scale.begin() + static_cast<std::ptrdiff_t>(out.count), request.scale_constant);
    } else {
      const GeomParam* p =
          request.scale_from == ScaleFrom::Widths ? c.param("widths") : c.param(request.scale_attribute);
      if (p == nullptr) {
        throw Error(fmt::format(
            "{}: no {} to take the scale from", where,
            request.scale_from == ScaleFrom::Widths ? "widths" : "attribute '" + request.scale_attribute + "'"));
      }
      expand_param(*p, sample_time, n, where, out.scale, base);
      const bool diameter = request.scale_from == ScaleFrom::Widths;
      for (std::uint64_t i = base; i < out.count; ++i) {
        float s = diameter ? scale_from_width(out.scale[i]) : out.scale[i];
        if (size_factor != 1.0) s = static_cast<float>(s * size_factor);
        out.scale[i] = s;
      }
    }
    if (request.color) {
      const GeomParam* cd = c.param("Cd");
      expand_param(*cd, sample_time, n, where, rgb_, 0);
      const std::vector<float>& rgb = rgb_;
      const std::size_t k = cd->values().header().extent;
      ensure_size(out.color, out.count * 4);
      std::uint8_t* dst = out.color.data() + base * 4;
      for (std::uint64_t i = 0; i < n; ++i) {
        for (std::size_t ch = 0; ch < 3; ++ch) dst[i * 4 + ch] = ch < k ? to_unorm8(rgb[i * k + ch]) : 0;
        dst[i * 4 + 3] = k >= 4 ? to_unorm8(rgb[i * k + 3]) : 255;
      }
    }
    if (request.velocity) {
      const SampleView v = c.points ? c.points->velocities(index) : c.mesh->velocities(index);
      if (v.size() != n) throw Error(fmt::format("{}: {} velocities for {} particles", where, v.size(), n));
      ensure_size(out.velocity, out.count * 3);
      float* vel = out.velocity.data() + base * 3;
      v.copy_raw(std::as_writable_bytes(std::span(vel, n * 3)));
      if (!identity) transform_points(m, vel, n, false);
    }
    if (request.id) {
      const SampleView ids = c.points->ids(index);
      if (ids.size() != n) throw Error(fmt::format("{}: {} ids for {} particles", where, ids.size(), n));  // 0 ids
      ensure_size(out.id, out.count);
      ids.copy_raw(std::as_writable_bytes(std::span(out.id.data() + base, n)));
    }
    for (std::size_t a = 0; a < request.floats.size(); ++a) {
      const GeomParam* p = c.param(request.floats[a]);
      expand_param(*p, sample_time, n, where, out.extra[a], base);
    }
  }

  static void transform_points(const Matrix44& m, float* xyz, std::uint64_t n, bool translate) {
    const double w = translate ? 1.0 : 0.0;
    for (std::uint64_t i = 0; i < n; ++i) {
      const double x = xyz[i * 3], y = xyz[i * 3 + 1], z = xyz[i * 3 + 2];
      for (int c = 0; c < 3; ++c)
        xyz[i * 3 + c] = static_cast<float>(x * m[0][c] + y * m[1][c] + z * m[2][c] + w * m[3][c]);
    }
  }

  // Linear blend of samples a and b (weight w of b) for particles present in both, matched by
  // id; particles only in a keep a's values.
  void blend(const Cooked& c, std::uint32_t a, std::uint32_t b, double w, double time, const Request& request,
             ParticleFrame& out) {
    if (!c.points || !c.points->has_ids()) {
      throw OptionError("interpolate", fmt::format("{}: interpolate: {}", archive_.name(), why_no_interpolation()));
    }
    Request r = request;
    r.id = true;
    ParticleFrame fa, fb;
    fa.clear(request.floats.size());
    fb.clear(request.floats.size());
    read_sample(c, a, time, r, fa);
    read_sample(c, b, time, r, fb);
    by_id_.clear();
    for (std::uint64_t j = 0; j < fb.count; ++j) by_id_.emplace(fb.id[j], j);
    const auto lerp = [w](float x, float y) { return static_cast<float>(x + (y - x) * w); };
    for (std::uint64_t i = 0; i < fa.count; ++i) {
      const auto it = by_id_.find(fa.id[i]);
      if (it == by_id_.end()) continue;
      const std::uint64_t j = it->second;
      for (int k = 0; k < 3; ++k) fa.position[i * 3 + k] = lerp(fa.position[i * 3 + k], fb.position[j * 3 + k]);
      fa.scale[i] = lerp(fa.scale[i], fb.scale[j]);
      if (request.velocity) {
        for (int k = 0; k < 3; ++k) fa.velocity[i * 3 + k] = lerp(fa.velocity[i * 3 + k], fb.velocity[j * 3 + k]);
      }
      if (request.color) {
        for (int k = 0; k < 4; ++k) {
          fa.color[i * 4 + k] = static_cast<std::uint8_t>(std::lround(lerp(fa.color[i * 4 + k], fb.color[j * 4 + k])));
        }
      }
      for (std::size_t e = 0; e < fa.extra.size(); ++e) {
        const std::size_t comps = float_components(request.floats[e]);
        for (std::size_t k = 0; k < comps; ++k)
          fa.extra[e][i * comps + k] = lerp(fa.extra[e][i * comps + k], fb.extra[e][j * comps + k]);
      }
    }
    append(fa, request, out);
  }

  // The nearest sample, every particle moved along its velocity to `time` (caches without ids).
  void advect_nearest(const Cooked& c, double time, const Request& request, ParticleFrame& out) {
    const auto index = static_cast<std::uint32_t>(c.sampling().near_index(time, c.samples()).first);
    Request r = request;
    r.velocity = true;
    ParticleFrame f;
    f.clear(request.floats.size());
    read_sample(c, index, time, r, f);
    const auto dt = static_cast<float>(time - c.sampling().sample_time(index));
    for (std::uint64_t i = 0; i < f.count * 3; ++i) f.position[i] += f.velocity[i] * dt;
    append(f, request, out);
  }

  void append(const ParticleFrame& f, const Request& request, ParticleFrame& out) const {
    const std::uint64_t base = out.count;
    out.count += f.count;
    const auto copy = [&](const auto& from, auto& to, std::size_t k) {
      ensure_size(to, out.count * k);
      std::copy_n(from.begin(), f.count * k, to.begin() + static_cast<std::ptrdiff_t>(base * k));
    };
    copy(f.position, out.position, 3);
    copy(f.scale, out.scale, 1);
    if (request.color) copy(f.color, out.color, 4);
    if (request.velocity) copy(f.velocity, out.velocity, 3);
    if (request.id) copy(f.id, out.id, 1);
    for (std::size_t e = 0; e < f.extra.size(); ++e)
      copy(f.extra[e], out.extra[e], float_components(request.floats[e]));
  }

  Archive archive_;
  std::vector<Cooked> objects_;
  std::unordered_map<std::uint64_t, std::uint64_t> by_id_;
  bool ids_known_ = false, ids_usable_ = false;
  std::vector<float> rgb_;  // Cd before conversion to RGBA8
};

}  // namespace

std::unique_ptr<Source> open_alembic(const Options& options, const std::function<void(const Progress&)>& progress) {
  return std::make_unique<AlembicSource>(options, progress);
}

}  // namespace pstream::cook
